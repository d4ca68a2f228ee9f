"""Step variants timed side by side on any backend, their numerics checked against the plain step, and profiles.

Usage: python -m bench.step_variants [--precisions bfloat16,default] [--variants base,cublaslt,...]
                                     [--method freenerf] [--batch_size 4096] [--repeats 5] [--profile_steps 5]
                                     [--out_dir DIR] [--tiny]
       python -m bench.step_variants --bindings VARIANT|fastest [--measured step_variants.json --precisions P]

A variant is a gin binding of the model (which the user sets the same way) and/or XLA compiler options (which a
user sets through XLA_FLAGS, e.g. XLA_FLAGS=--xla_gpu_enable_cublaslt=true). Per precision, every variant's step
is compiled from the same state, run once (its loss and parameters after that step are compared with the plain
step's), then all are timed interleaved (A, B, C, A, B, C, ...) and the median reported with the rate of the
step's matmul flops (bench.roofline) and of XLA's count of the traced step (which misses the Pallas variants'
kernels: read their matmul rate). An option this XLA does not know, or a kernel that does not build, is reported as
unavailable, not an error. With --profile_steps, the plain step and the fastest variant of each precision are
traced (bench.kernel_profile): kernels per kind and the longest kernels, trace files in --out_dir.
The tables print (and step_variants.json is written) after each precision.
--bindings prints a variant's name and then its gin bindings, one a line (bench/gpu_check.sh trains with them);
`fastest` names the fastest variant a run can take (gin bindings only, its first step's loss within 1e-3 of the
plain step's) measured at one precision in --measured, or base when none is faster or nothing was measured.
"""

import argparse
import json
import os
import sys

import jax
import numpy as np

from bench import common
from bench import device
from bench import kernel_profile
from bench import roofline
from internal import cli
from internal.models import mip_nerf
from internal.models import precision

RELU_FROM_OUTPUT = ('MLP.net_activation = @relu_from_output',)
PALLAS = ("MLP.dense_kernel = 'pallas'",)
CUBLASLT = {'xla_gpu_enable_cublaslt': True}  # Lets XLA fuse bias and ReLU into the matmul's epilogue.
VARIANTS = {'base': ((), {}),
            'relu_from_output': (RELU_FROM_OUTPUT, {}),
            'cublaslt': ((), CUBLASLT),
            'cublaslt_relu_from_output': (RELU_FROM_OUTPUT, CUBLASLT),
            'triton_gemm_off': ((), {'xla_gpu_enable_triton_gemm': False}),
            'triton_gemm_any': ((), {'xla_gpu_triton_gemm_any': True}),
            # The hidden layers as fused Pallas kernels (internal/models/fused_dense.py), at three tilings.
            'pallas': (PALLAS, {}),
            'pallas_rows128': (PALLAS + ('FusedDenseTiles.rows = 128',), {}),
            'pallas_block64': (PALLAS + ('FusedDenseTiles.block = 64', 'FusedDenseTiles.num_warps = 4'), {})}


def model_bindings(variant: str) -> tuple:
  """The gin bindings of a variant a run can train with (ValueError for one that sets XLA options)."""
  bindings, options = VARIANTS[variant]
  if options:
    raise ValueError(f'step variant {variant!r} sets XLA options {sorted(options)}; a run takes gin bindings only '
                     '(set XLA options through XLA_FLAGS)')
  return bindings


def fastest(report: dict, precision_name: str) -> str:
  """The fastest variant of report at a precision that a run can take and that kept the first step's loss."""
  figures = report['results'].get(precision_name, {})
  if 'step_seconds' not in figures.get('base', {}):
    return 'base'
  tolerance = 1e-3 * abs(figures['base']['loss'])
  times = {variant: f['step_seconds'] for variant, f in figures.items()
           if 'step_seconds' in f and not VARIANTS[variant][1] and abs(f.get('loss_difference', 0)) <= tolerance}
  return min(times, key=times.get)


def print_bindings(variant: str, measured: str, precisions) -> None:
  """Prints a variant's name (fastest: resolved from the measured file) and its gin bindings, one a line."""
  if variant == 'fastest':
    if len(precisions) != 1:
      raise ValueError(f'--bindings fastest: --precisions must name one precision, not {precisions}')
    variant = fastest(json.load(open(measured)), precisions[0]) if os.path.isfile(measured) else 'base'
  elif variant not in VARIANTS:
    raise ValueError(f"--bindings {variant!r}: expected 'fastest' or one of {list(VARIANTS)}")
  print('\n'.join((variant,) + model_bindings(variant)))


def build(variant: str, precision_name: str, args, batch):
  """(runner, figures) of one compiled variant, figures holding its first step's loss and parameters."""
  bindings, options = VARIANTS[variant]
  config = device.method_config(args.method, precision_name, args.batch_size,
                                (device.TINY if args.tiny else []) + list(bindings))
  model = mip_nerf.MipNerfModel(white_background=config.white_background, precision=precision_name)
  run, holder, xla = common.step_runner(config, model, batch, compiler_options=options or None)
  figures = {'loss': float(holder[1]['loss']), 'xla_flops': xla['flops'], 'xla_step_bytes': xla['bytes'],
             'matmul_flops': sum(layer.flops() for layer in roofline.step_layers(config, model)),
             'params': [np.asarray(x) for x in jax.tree.leaves(holder[0].params)]}
  return run, figures


def numerics_against(figures, base) -> dict:
  """Whether a variant's first step matches the plain step's: loss and parameters, exactly or how far."""
  gaps = [float(np.max(np.abs(a - b))) for a, b in zip(figures['params'], base['params'])]
  return {'loss_equal': figures['loss'] == base['loss'], 'loss_difference': figures['loss'] - base['loss'],
          'params_equal': max(gaps) == 0, 'max_param_difference': max(gaps)}


def measure_precision(precision_name: str, args, batch):
  """{variant: figures} of every available variant at one precision (unavailable ones with their reason)."""
  runners, results = {}, {}
  for variant in args.variants:
    try:
      runners[variant], results[variant] = build(variant, precision_name, args, batch)
    # An XLA option this version lacks, a kernel Triton cannot build: one variant's failure must not cost the
    # others their measurement.
    except Exception as error:  # pylint: disable=broad-except
      results[variant] = {'unavailable': str(error).splitlines()[0][:200]}
    print(f'{precision_name} {variant}: compiled', flush=True)
  times = common.interleaved_medians(runners, args.repeats)
  base = results.get('base')
  for variant, seconds in times.items():
    figures = results[variant]
    figures.update(step_seconds=seconds, rays_per_s=args.batch_size / seconds,
                   matmul_tflops=figures['matmul_flops'] / seconds / 1e12,
                   xla_tflops=figures['xla_flops'] / seconds / 1e12)
    if base and 'step_seconds' in base:
      figures.update(numerics_against(figures, base), vs_base=seconds / times['base'])
  if args.profile_steps:
    quickest = min(times, key=times.get)
    for variant in [v for v in dict.fromkeys(('base', quickest)) if v in runners]:
      trace_file = os.path.join(args.out_dir, f'trace_{precision_name}_{variant}.json.gz') if args.out_dir else ''
      trace = kernel_profile.record(runners[variant], args.profile_steps, trace_file)
      results[variant]['profile'] = kernel_profile.summarise(kernel_profile.device_kernels(trace), args.profile_steps)
  for figures in results.values():
    figures.pop('params', None)
  return results


def table(report) -> str:
  """Markdown: per precision and variant the median step, its ratio to the plain step, rates and numerics."""
  lines = ['| precision | variant | step ms | vs base | matmul TFLOP/s | XLA-count TFLOP/s | first step vs base |',
           '|---|---|---|---|---|---|---|']
  for name, variants in report['results'].items():
    for variant, f in variants.items():
      if 'unavailable' in f:
        lines.append(f"| {name} | {variant} | unavailable: {f['unavailable']} | | | | |")
        continue
      same = ('identical' if f.get('params_equal') else
              f"loss {f.get('loss_difference', 0):+.2e}, params within {f.get('max_param_difference', 0):.1e}")
      lines.append(f"| {name} | {variant} | {f['step_seconds'] * 1e3:.2f} | {f.get('vs_base', 1):.3f} | "
                   f"{f['matmul_tflops']:.3g} | {f['xla_tflops']:.3g} | {same if variant != 'base' else ''} |")
  return '\n'.join(lines)


def profile_tables(report) -> str:
  """The kernel profiles of report, one block per profiled (precision, variant)."""
  return '\n\n'.join(kernel_profile.table(f'{name}, {variant}', f['profile'])
                     for name, variants in report['results'].items()
                     for variant, f in variants.items() if 'profile' in f)


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--precisions', default='bfloat16,default')
  parser.add_argument('--variants', default=','.join(VARIANTS))
  parser.add_argument('--method', default='freenerf', choices=['mipnerf', 'freenerf'])
  parser.add_argument('--batch_size', type=int, default=4096)
  parser.add_argument('--repeats', type=int, default=5)
  parser.add_argument('--profile_steps', type=int, default=5, help='0: no profile')
  parser.add_argument('--out_dir', default='', help='step_variants.json and the traces go here')
  parser.add_argument('--tiny', action='store_true', help='a 2 x 32 MLP with 8 samples (for tests)')
  parser.add_argument('--bindings', default='', help='VARIANT or fastest: print its name and gin bindings')
  parser.add_argument('--measured', default='', help="a step_variants.json for --bindings fastest")
  args = parser.parse_args(argv)
  names = common.names_of(args.precisions, precision.PRECISIONS, '--precisions')
  if args.bindings:
    return print_bindings(args.bindings, args.measured, names)
  args.variants = common.names_of(args.variants, VARIANTS, '--variants')
  if 'base' not in args.variants:
    args.variants.insert(0, 'base')
  if args.out_dir:
    os.makedirs(args.out_dir, exist_ok=True)
  batch = common.dtu_like_batch(args.batch_size)
  report = {'device': jax.devices()[0].device_kind, 'platform': jax.devices()[0].platform,
            'jax_version': jax.__version__,
            'command': cli.command_line('bench.step_variants', argv),
            'method': args.method, 'batch_size': args.batch_size, 'repeats': args.repeats, 'tiny': args.tiny,
            'results': {}}
  for name in names:  # Written after each precision: a run stopped part way keeps what it measured.
    report['results'][name] = measure_precision(name, args, batch)
    text = f"{report['device']}, jax {report['jax_version']}: `{report['command']}`\n\n{table(report)}"
    profiles = profile_tables(report)
    print(text + ('\n\n' + profiles if profiles else ''), flush=True)
    if args.out_dir:
      with open(os.path.join(args.out_dir, 'step_variants.json'), 'w') as f:
        json.dump(report, f, indent=1)


if __name__ == '__main__':
  sys.exit(cli.run(main))
