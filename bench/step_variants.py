"""Step variants timed side by side on any backend, their numerics checked against the plain step, and profiles.

Usage: python -m bench.step_variants [--precisions bfloat16,default] [--variants base,cublaslt,...]
                                     [--method freenerf] [--batch_size 4096] [--repeats 5] [--profile_steps 5]
                                     [--out_dir DIR] [--tiny]
       python -m bench.step_variants --bindings VARIANT|fastest [--measured step_variants.json --precisions P]

A variant is a gin binding of the model (which the user sets the same way) and/or XLA compiler options (which a
user sets through XLA_FLAGS, e.g. XLA_FLAGS=--xla_gpu_enable_cublaslt=true). Per precision, every variant's step
is compiled from the same state and run once (its loss and parameters after that step are compared with the plain
step's, and the gradients of its loss at the initial parameters with the plain loss's), then all are timed
interleaved (A, B, C, A, B, C, ...) and the median reported with the rate of the step's matmul flops
(bench.roofline) and of XLA's count of the traced step (which misses the Pallas variants' kernels: read their
matmul rate). Each variant is built, timed and profiled in its own guard: an option this XLA does not know, a
kernel that does not build or fails while timed, is reported as unavailable with the last ERROR_LINES lines of
its error (in step_variants.json and the log), and the others keep their measurement. With --profile_steps, the
plain step and the fastest variant of each precision are traced (bench.kernel_profile): kernels per kind and the
longest kernels, trace files in --out_dir. The tables print (and step_variants.json is written, with provenance)
after each precision.
--bindings prints a variant's name and then its gin bindings, one a line (bench/gpu_check.sh trains with them);
`fastest` (the function fastest(report, precision)) names the fastest variant a run can take, measured at one
precision in --measured, or base when none is faster or nothing was measured: gin bindings only, its first
step's loss within 1e-3 of the plain step's, its gradients within gradient_tolerance of the plain step's (relative
L2 of all together, each parameter array within LEAF_FACTOR times that).
"""

import argparse
import json
import os
import sys
import time
import traceback

import jax
from jax import random
import numpy as np

from bench import common
from bench import device
from bench import kernel_profile
from bench import roofline
from internal import cli
from internal.models import mip_nerf
from internal.models import precision
from internal.training import train_step as ts
from tools import provenance

RELU_FROM_OUTPUT = ('MLP.net_activation = @relu_from_output',)
PALLAS = ("MLP.dense_kernel = 'pallas'",)
FOLDED_BIAS = ("MLP.dense_kernel = 'folded_bias'",)
CUBLASLT = {'xla_gpu_enable_cublaslt': True}  # Lets XLA fuse bias and ReLU into the matmul's epilogue.
VARIANTS = {'base': ((), {}),
            'relu_from_output': (RELU_FROM_OUTPUT, {}),
            'cublaslt': ((), CUBLASLT),
            'cublaslt_relu_from_output': (RELU_FROM_OUTPUT, CUBLASLT),
            'triton_gemm_off': ((), {'xla_gpu_enable_triton_gemm': False}),
            'triton_gemm_any': ((), {'xla_gpu_triton_gemm_any': True}),
            # The hidden layers as fused Pallas kernels (internal/models/fused_dense.py), at four tilings; longer
            # row tiles re-read the weights less (the 256-row dx tile's steps halved to fit shared memory).
            'pallas': (PALLAS, {}),
            'pallas_rows128': (PALLAS + ('FusedDenseTiles.rows = 128',), {}),
            'pallas_rows256': (PALLAS + ('FusedDenseTiles.rows = 256', 'FusedDenseTiles.chunk = 32'), {}),
            'pallas_block64': (PALLAS + ('FusedDenseTiles.block = 64', 'FusedDenseTiles.num_warps = 4'), {}),
            # Fewer passes over the activations (docs/benchmarks.md says what each should save): the previous
            # ReLU's mask applied where dx is stored; the skip and first layers read without concatenated or
            # padded copies; both; XLA's layers with each bias folded into its kernel (no Pallas).
            'pallas_mask_at_store': (PALLAS + ('FusedDensePasses.mask_at_store = True',), {}),
            'pallas_two_inputs': (PALLAS + ('FusedDensePasses.two_inputs = True',), {}),
            'pallas_fewer_passes': (PALLAS + ('FusedDensePasses.mask_at_store = True',
                                              'FusedDensePasses.two_inputs = True'), {}),
            'folded_bias': (FOLDED_BIAS, {}),
            'folded_bias_cublaslt': (FOLDED_BIAS, CUBLASLT)}


ERROR_LINES = 30  # The last lines of a failed variant's traceback kept in the JSON and the log.
LOSS_TOLERANCE = 1e-3  # A variant's first loss may differ from the plain step's by this fraction of it.


def model_bindings(variant: str) -> tuple:
  """The gin bindings of a variant a run can train with (ValueError for one that sets XLA options)."""
  bindings, options = VARIANTS[variant]
  if options:
    raise ValueError(f'step variant {variant!r} sets XLA options {sorted(options)}; a run takes gin bindings only '
                     '(set XLA options through XLA_FLAGS)')
  return bindings


# Each parameter array's gradient may differ by this many times the tolerance of all together: the deepest layers'
# small arrays carry the most rounding (the paper model in float32 on a CPU, results/cpu/pallas_interpreted: the
# fused layer's Dense_0 kernel within 4.9e-5, all together within 4.8e-6), while a wrong kernel is off by far more.
LEAF_FACTOR = 10


def gradient_tolerance(precision_name: str, platform: str) -> float:
  """The relative L2 by which a variant's gradients (all together; each array LEAF_FACTOR times it) may differ
  from the plain step's: 1e-5 where the matmuls are exact float32, 2e-2 where they round (bfloat16; 'default',
  TF32 on an NVIDIA GPU)."""
  dtype, matmul_precision = precision.settings(precision_name)
  exact = np.dtype(dtype) == np.float32 and (matmul_precision == jax.lax.Precision.HIGHEST or platform == 'cpu')
  return 1e-5 if exact else 2e-2


def refusal(variant: str, figures: dict, base: dict, precision_name: str, platform: str) -> str:
  """Why a run may not take a measured variant ('' if it may): XLA options, not timed, or numerics off."""
  if VARIANTS[variant][1]:
    return 'sets XLA options'
  if 'step_seconds' not in figures:
    return 'not timed'
  if variant == 'base':
    return ''
  if 'gradient_worst_relative_l2' not in figures or 'gradient_relative_l2' not in figures:
    return 'no gradient check'
  if abs(figures.get('loss_difference', np.inf)) > LOSS_TOLERANCE * abs(base['loss']):
    return f"first loss off by {figures.get('loss_difference', np.inf):+.2e}"
  tolerance = gradient_tolerance(precision_name, platform)
  if not figures['gradient_relative_l2'] <= tolerance:  # NaN too.
    return f"gradients off by {figures['gradient_relative_l2']:.1e} (relative L2 > {tolerance:.0e})"
  if not figures['gradient_worst_relative_l2'] <= LEAF_FACTOR * tolerance:
    return (f"gradients off: {figures['gradient_worst_leaf']} by {figures['gradient_worst_relative_l2']:.1e} "
            f'(relative L2 > {LEAF_FACTOR * tolerance:.0e})')
  return ''


def fastest(report: dict, precision_name: str) -> str:
  """The fastest variant of report at a precision that a run can take (refusal(...) == ''), else base."""
  figures = report['results'].get(precision_name, {})
  base = figures.get('base', {})
  if 'step_seconds' not in base:
    return 'base'
  times = {variant: f['step_seconds'] for variant, f in figures.items() if variant in VARIANTS and
           not refusal(variant, f, base, precision_name, report.get('platform', 'gpu'))}
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
  """(runner, figures) of one compiled variant, figures holding its first step's loss and parameters and the
  gradients of its loss at the initial parameters (named leaves)."""
  start = time.perf_counter()
  bindings, options = VARIANTS[variant]
  config = device.method_config(args.method, precision_name, args.batch_size,
                                (device.TINY if args.tiny else []) + list(bindings))
  model = mip_nerf.MipNerfModel(white_background=config.white_background, precision=precision_name)
  run, holder, xla = common.step_runner(config, model, batch, compiler_options=options or None)
  figures = {'loss': float(holder[1]['loss']), 'xla_flops': xla['flops'], 'xla_step_bytes': xla['bytes'],
             'matmul_flops': sum(layer.flops() for layer in roofline.step_layers(config, model)),
             'params': [np.asarray(x) for x in jax.tree.leaves(holder[0].params)],
             'gradients': first_gradients(config, model, batch, options)}
  figures['build_seconds'] = time.perf_counter() - start  # Compiling the step and its gradients, the first step.
  return run, figures


def first_gradients(config, model, batch, options) -> dict:
  """{parameter name: float64 gradient} of the step's loss at its initial parameters, batch and key."""
  _, state = ts.create_train_state(config, random.PRNGKey(0), batch.rays)
  step = state.step + 1
  loss = lambda params: ts.compute_loss(config, model, params, batch, random.fold_in(random.PRNGKey(1), step),
                                        step)[0]
  grad = jax.jit(jax.grad(loss)).lower(state.params).compile(compiler_options=options or None)
  return {jax.tree_util.keystr(path): np.asarray(leaf, np.float64)
          for path, leaf in jax.tree_util.tree_leaves_with_path(grad(state.params))}


def numerics_against(figures, base) -> dict:
  """How a variant's first step compares with the plain step's: loss, parameters after it, and the relative L2
  of the gradients (all parameters together, and the worst parameter array)."""
  gaps = [float(np.max(np.abs(a - b))) for a, b in zip(figures['params'], base['params'])]
  relative = {name: _relative_l2(grad, base['gradients'][name]) for name, grad in figures['gradients'].items()}
  worst = max(relative, key=lambda name: np.nan_to_num(relative[name], nan=np.inf))
  together = [np.concatenate([g.ravel() for g in grads.values()]) for grads in (figures['gradients'],
                                                                                base['gradients'])]
  return {'loss_equal': figures['loss'] == base['loss'], 'loss_difference': figures['loss'] - base['loss'],
          'params_equal': max(gaps) == 0, 'max_param_difference': max(gaps),
          'gradient_relative_l2': _relative_l2(*together), 'gradient_worst_relative_l2': relative[worst],
          'gradient_worst_leaf': worst}


def _relative_l2(a, b) -> float:
  """|a - b| / |b| (0 where both are 0)."""
  scale = np.linalg.norm(b)
  return float(np.linalg.norm(a - b) / scale) if scale else float(np.linalg.norm(a) and np.inf)


def failure(stage: str, error: BaseException, prefix: str = '') -> dict:
  """{'unavailable': one line, 'error_tail': the last ERROR_LINES lines of the traceback} of a stage's error
  (the keys after prefix)."""
  first = (str(error).strip().splitlines() or [''])[0]
  tail = ''.join(traceback.format_exception(error)).rstrip().splitlines()[-ERROR_LINES:]
  return {prefix + 'unavailable': f'{stage}: {type(error).__name__}: {first}'[:200], prefix + 'error_tail': tail}


def guarded(stage: str, variant: str, precision_name: str, results: dict, work, prefix: str = ''):
  """work() or None: its error is the variant's failure (failure(...), also printed), not the whole run's."""
  try:
    return work()
  # An XLA option this version lacks, a kernel Triton cannot build or that fails on the device: one variant's
  # failure must not cost the others their measurement.
  except Exception as error:  # pylint: disable=broad-except
    results[variant] = dict(results.get(variant, {}), **failure(stage, error, prefix))
    print(f'{precision_name} {variant}: {stage} failed; the last lines of its error:\n' +
          '\n'.join('  ' + line for line in results[variant][prefix + 'error_tail']), flush=True)
    return None


def guarded_medians(runners: dict, repeats: int, precision_name: str, results: dict) -> dict:
  """{variant: median seconds} of runners run interleaved; a runner that fails is dropped, its failure recorded."""
  times = {variant: [] for variant in runners}
  for _ in range(repeats):
    for variant, run in list(runners.items()):
      seconds = guarded('timing', variant, precision_name, results, run)
      if seconds is None:
        del runners[variant], times[variant]
      else:
        times[variant].append(seconds)
  return {variant: float(np.median(t)) for variant, t in times.items()}


def measure_precision(precision_name: str, args, batch, platform: str = 'gpu'):
  """{variant: figures} of every available variant at one precision (unavailable ones with their reason)."""
  runners, results, start = {}, {}, time.perf_counter()
  for variant in args.variants:
    if args.build_seconds and time.perf_counter() - start > args.build_seconds:
      # A lease's stage limit would otherwise cut the run before any variant is timed and written.
      results[variant] = {'unavailable': f'not built: --build_seconds {args.build_seconds:g} spent on the others'}
      print(f'{precision_name} {variant}: {results[variant]["unavailable"]}', flush=True)
      continue
    built = guarded('build', variant, precision_name, results,
                    lambda variant=variant: build(variant, precision_name, args, batch))
    if built:
      runners[variant], results[variant] = built
    print(f'{precision_name} {variant}: {"compiled" if built else "unavailable"}', flush=True)
  times = guarded_medians(runners, args.repeats, precision_name, results)
  base = results.get('base')
  for variant, seconds in times.items():
    figures = results[variant]
    figures.update(step_seconds=seconds, rays_per_s=args.batch_size / seconds,
                   matmul_tflops=figures['matmul_flops'] / seconds / 1e12,
                   xla_tflops=figures['xla_flops'] / seconds / 1e12)
    if 'base' in times:
      figures.update(numerics_against(figures, base), vs_base=seconds / times['base'])
      figures['refused'] = refusal(variant, figures, base, precision_name, platform)
  if args.profile_steps and times:
    quickest = min(times, key=times.get)
    for variant in [v for v in dict.fromkeys(('base', quickest)) if v in runners]:
      trace_file = os.path.join(args.out_dir, f'trace_{precision_name}_{variant}.json.gz') if args.out_dir else ''
      trace = guarded('profile', variant, precision_name, results,
                      lambda variant=variant: kernel_profile.record(runners[variant], args.profile_steps, trace_file),
                      prefix='profile_')
      if trace is not None:
        results[variant]['profile'] = kernel_profile.summarise(kernel_profile.device_kernels(trace),
                                                               args.profile_steps)
  for figures in results.values():
    figures.pop('params', None)
    figures.pop('gradients', None)
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
      same = ('identical' if f.get('params_equal') and f.get('gradient_relative_l2') == 0 else
              f"loss {f.get('loss_difference', 0):+.2e}, params within {f.get('max_param_difference', 0):.1e}, "
              f"gradients within {f.get('gradient_worst_relative_l2', np.nan):.1e}")
      same += f"; refused: {f['refused']}" if f.get('refused') else ''
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
  parser.add_argument('--build_seconds', type=float, default=0.,
                      help='stop building variants after this long and time those built (0: build all)')
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
            'provenance': provenance.record(['python', '-m', 'bench.step_variants'] +
                                            list(sys.argv[1:] if argv is None else argv)),
            'method': args.method, 'batch_size': args.batch_size, 'repeats': args.repeats, 'tiny': args.tiny,
            'results': {}}
  for name in names:  # Written after each precision: a run stopped part way keeps what it measured.
    report['results'][name] = measure_precision(name, args, batch, report['platform'])
    text = f"{report['device']}, jax {report['jax_version']}: `{report['command']}`\n\n{table(report)}"
    profiles = profile_tables(report)
    print(text + ('\n\n' + profiles if profiles else ''), flush=True)
    if args.out_dir:
      with open(os.path.join(args.out_dir, 'step_variants.json'), 'w') as f:
        json.dump(report, f, indent=1)


if __name__ == '__main__':
  sys.exit(cli.run(main))
