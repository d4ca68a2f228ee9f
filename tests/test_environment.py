"""The backend line, the warning for an NVIDIA GPU that jax does not use, and `--env` for bug reports."""

import importlib.metadata
import os
import platform
import subprocess
import sys
import types

import jax
import pytest

from internal import environment
from test_checkpoints import ROOT


def test_an_nvidia_gpu_is_seen_from_the_driver_or_nvidia_smi(tmp_path):
  no_smi = lambda name: None
  assert not environment.nvidia_gpu_present(str(tmp_path), no_smi)
  assert environment.nvidia_gpu_present(str(tmp_path), lambda name: '/usr/bin/nvidia-smi')
  (tmp_path / 'gpus').mkdir()  # /proc/driver/nvidia/gpus/ of a loaded driver.
  assert environment.nvidia_gpu_present(str(tmp_path), no_smi)


def test_the_backend_line_counts_devices_per_kind():
  gpu = types.SimpleNamespace(platform='gpu', device_kind='NVIDIA H100 80GB HBM3')
  assert environment.backend_line([gpu, gpu]) == 'jax backend: gpu, 2 devices: 2 x NVIDIA H100 80GB HBM3'
  devices = jax.devices()  # One kind on any test machine.
  assert environment.backend_line() == (f'jax backend: {devices[0].platform}, {len(devices)} '
                                        f'device{"s" * (len(devices) > 1)}: {len(devices)} x {devices[0].device_kind}')


def test_the_warning_only_for_a_gpu_machine_on_the_cpu_not_asked_for():
  warning = environment.cpu_fallback_warning('cpu', True)
  assert warning.startswith('warning: ') and 'pip install -r requirements-gpu.txt' in warning
  assert environment.cpu_fallback_warning('gpu', True) is None
  assert environment.cpu_fallback_warning('cpu', False) is None
  assert environment.cpu_fallback_warning('cpu', True, platforms='cpu') is None


def _run(args, env=None):
  return subprocess.run([sys.executable] + args, cwd=ROOT, capture_output=True, text=True, timeout=120,
                        check=False, env=env)


@pytest.mark.skipif(jax.default_backend() != 'cpu', reason='jax runs on an accelerator here: no CPU fallback to see')
def test_train_prints_the_backend_line_and_warns_on_a_gpu_machine_without_cuda_jax(tmp_path):
  smi = tmp_path / 'nvidia-smi'  # A machine with an NVIDIA driver, as far as the check can see.
  smi.write_text('#!/bin/sh\nexit 0\n')
  smi.chmod(0o755)
  env = {k: v for k, v in os.environ.items() if k != 'JAX_PLATFORMS'}
  env['PATH'] = f'{tmp_path}{os.pathsep}{env["PATH"]}'
  proc = _run(['train.py', '--gin_bindings', 'Config.batch_size = -1'], env)  # Stops at the setting's check.
  assert proc.returncode == 2
  assert proc.stdout.splitlines()[0].startswith('jax backend: cpu, ')
  assert proc.stderr.splitlines()[0].startswith('warning: an NVIDIA GPU is present but jax sees only the CPU')
  assert proc.stderr.splitlines()[1].startswith('error: ') and 'Config.batch_size' in proc.stderr


def test_env_prints_the_environment_and_help_names_it():
  proc = _run(['train.py', '--env'])
  assert proc.returncode == 0, proc.stderr
  lines = proc.stdout.splitlines()
  assert f'jax: {jax.__version__}' in lines and f'numpy: {importlib.metadata.version("numpy")}' in lines
  assert environment.backend_line() in lines
  assert any(line.startswith('precision: x64 off') for line in lines)
  for script in ('train.py', 'eval.py', 'render.py'):
    assert '--env' in _run([script, '--help']).stdout


def test_cpu_isa_is_the_widest_level_the_flags_have_and_a_cap_of_xla_flags_apart(tmp_path):
  cpuinfo = tmp_path / 'cpuinfo'
  cpuinfo.write_text('model name\t: AMD EPYC\nflags\t\t: fpu sse4_2 avx avx2 fma avx512f avx512bw\n')
  assert environment.cpu_isa(str(cpuinfo), xla_flags='') == 'AVX512'
  # A cap changes XLA's own code, not the kernels the CPU's libraries pick: not the capped level's kind.
  assert environment.cpu_isa(str(cpuinfo), xla_flags='--xla_cpu_max_isa=AVX2') == 'AVX512_max_AVX2'
  assert environment.cpu_isa(str(cpuinfo), xla_flags='--xla_cpu_max_isa=avx') == 'AVX512_max_AVX'
  assert environment.cpu_isa(str(cpuinfo), xla_flags='--xla_cpu_max_isa=AVX512') == 'AVX512'
  cpuinfo.write_text('flags\t\t: fpu sse4_2 avx avx2\n')  # AVX2 without FMA is not XLA's AVX2 target.
  assert environment.cpu_isa(str(cpuinfo), xla_flags='') == 'AVX'
  assert environment.cpu_isa(str(cpuinfo), xla_flags='--xla_cpu_max_isa=AVX512') == 'AVX'
  assert environment.cpu_isa(str(tmp_path / 'missing'), xla_flags='') == platform.machine()
