"""Device benchmark on any backend: train steps, rendering and memory of each method at each Config.precision.

Usage: python -m bench.device [--batch_size 4096] [--precisions float32,default,bfloat16]
                              [--methods mipnerf,freenerf] [--repeats 5] [--render_rays 16384] [--out FILE]

The paper model (8 x 256 MLP, 2 levels x 128 samples) with each method's DTU 3-view gin config (random DTU-like
rays, no data needed; RegNeRF's step also takes as many random-pose rays in 8 x 8 patches). Per precision, the
methods' steps and a matmul at that precision run interleaved (A, B, M, A, B, M, ...); figures are medians over
--repeats after a warm-up step:
  step time, rays/s, XLA's flop count of the compiled step / step time = achieved TFLOP/s, against the best
  [m, k] @ [k, n] rate at the same dtype and matmul precision (the MLP's [B | B*S, W] @ [W, W] and a
  square of side min(B, 4096)); rendering rays/s (chunks of Config.render_chunk_size, no normals); XLA's memory
  estimate of the compiled step; the process's peak memory after that precision's runs (the device's
  peak_bytes_in_use, or the host's peak RSS where the device reports none; a running maximum).
The JSON of --out also records the provenance (commit, machine, date: tools/provenance.py).
"""

import argparse
import json
import os
import resource
import sys

import gin
import jax
import jax.numpy as jnp

from bench import common
from internal import cli
from internal import configs
from internal.evaluation import inference
from internal.models import mip_nerf
from internal.models import precision
from tools import provenance

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
METHOD_CONFIGS = {'mipnerf': 'configs/mipnerf/dtu3_mipnerf.gin',
                  'freenerf': 'configs/freenerf/dtu3_freenerf.gin',
                  'regnerf': 'configs/regnerf/dtu3_regnerf.gin'}
TINY = ['MLP.net_depth = 2', 'MLP.net_width = 32', 'MLP.net_width_viewdirs = 16', 'MipNerfModel.num_samples = 8']
MATMUL_RUNS = 5  # Best of 5 runs of each shape per repeat.


def available_methods():
  """Methods whose DTU 3-view gin config exists in this checkout."""
  return [m for m, path in METHOD_CONFIGS.items() if os.path.isfile(os.path.join(ROOT, path))]


def method_config(method: str, precision_name: str, batch_size: int, bindings) -> configs.Config:
  """The validated Config of method's gin file (parsed now, replacing any earlier bindings) at a precision, with
  RegNeRF's random-pose rays as many as the training rays (the paper's 4096 and 4096)."""
  random_rays = {'batch_size_random': batch_size} if method == 'regnerf' else {}
  return common.gin_config([os.path.join(ROOT, METHOD_CONFIGS[method])], bindings, precision=precision_name,
                           batch_size=batch_size, **random_rays)


def peak_memory():
  """(bytes, source) of the process's peak memory so far: the device's own count, else the host's RSS."""
  stats = jax.devices()[0].memory_stats()
  if stats and 'peak_bytes_in_use' in stats:
    return stats['peak_bytes_in_use'], 'device peak_bytes_in_use'
  return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, 'host peak RSS (no device memory stats)'


def measure_precision(name, methods, args, bindings):
  """{'matmul_peak_tflops', 'methods': {method: figures}, 'peak_memory_bytes', 'memory_source'} at one precision."""
  batch = common.dtu_like_batch(args.batch_size)
  steps, renders = {}, {}
  for method in methods:
    # The model's gin bindings are read when it is traced, so each method is compiled right after its parse.
    config = method_config(method, name, args.batch_size, bindings)
    model = mip_nerf.MipNerfModel(white_background=config.white_background, precision=name)
    steps[method] = common.step_runner(config, model, common.with_patches(batch, config))
    params = jax.tree.map(jnp.copy, steps[method][1][0].params)  # The timed steps donate the state's.
    renders[method] = common.render_runner(
        inference.make_render_fn(config, model, params, config.max_steps), args.render_rays,
        config.render_chunk_size)
    width, samples = mip_nerf.MLP().net_width, model.num_samples
  dtype, matmul_precision = precision.settings(name)
  rows = args.batch_size * samples
  shapes = ((args.batch_size, width, width), (rows, width, width), (min(args.batch_size, 4096),) * 3)
  runners = {method: run for method, (run, _, _) in steps.items()}
  runners['matmul'] = common.matmul_runner(shapes, min, MATMUL_RUNS, dtype, matmul_precision)
  times = common.interleaved_medians(runners, args.repeats)
  render_times = common.interleaved_medians(renders, args.repeats)
  peak = 1 / times.pop('matmul') / 1e12
  figures = {}
  for method, seconds in times.items():
    xla = steps[method][2]
    achieved = xla['flops'] / seconds / 1e12
    figures[method] = {'step_seconds': seconds, 'rays_per_s': args.batch_size / seconds,
                       'step_tflop': xla['flops'] / 1e12, 'achieved_tflops': achieved,
                       'fraction_of_peak': achieved / peak, 'xla_step_bytes': xla['bytes'],
                       'render_rays_per_s': args.render_rays / render_times[method]}
  memory, source = peak_memory()
  return {'matmul_peak_tflops': peak, 'matmul_shapes': shapes, 'methods': figures,
          'peak_memory_bytes': memory, 'memory_source': source}


TABLE_HEAD = ' | '.join(('precision', 'method', 'step ms', 'rays/s', 'TFLOP/s', 'peak TFLOP/s', 'of peak',
                          'render rays/s', 'XLA step GB', 'peak mem GB'))


def table_rows(name: str, result) -> str:
  """Plain-text table rows (TABLE_HEAD's columns) of one precision's measure_precision(...) result."""
  return '\n'.join(' | '.join([
      name, method, f'{1e3 * f["step_seconds"]:.1f}', f'{f["rays_per_s"]:.0f}', f'{f["achieved_tflops"]:.3g}',
      f'{result["matmul_peak_tflops"]:.3g}', f'{f["fraction_of_peak"]:.2f}', f'{f["render_rays_per_s"]:.0f}',
      f'{f["xla_step_bytes"] / 2**30:.3g}', f'{result["peak_memory_bytes"] / 2**30:.2f}'])
      for method, f in result['methods'].items())


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--batch_size', type=int, default=4096)
  parser.add_argument('--precisions', default=','.join(precision.PRECISIONS))
  parser.add_argument('--methods', default=','.join(available_methods()))
  parser.add_argument('--repeats', type=int, default=5)
  parser.add_argument('--render_rays', type=int, default=16384)
  parser.add_argument('--tiny', action='store_true', help='a 2 x 32 MLP with 8 samples (for tests)')
  parser.add_argument('--out', default='', help='JSON file for the results')
  args = parser.parse_args(argv)
  names = common.names_of(args.precisions, precision.PRECISIONS, '--precisions')
  methods = common.names_of(args.methods, available_methods(), '--methods')
  bindings = TINY if args.tiny else []
  words = ['python', '-m', 'bench.device'] + list(sys.argv[1:] if argv is None else argv)
  report = {'device': jax.devices()[0].device_kind, 'platform': jax.devices()[0].platform,
            'jax_version': jax.__version__, 'command': cli.recorded_command(words),
            'provenance': provenance.record(words),
            'batch_size': args.batch_size, 'repeats': args.repeats, 'render_rays': args.render_rays,
            'tiny': args.tiny, 'results': {}}
  print(f'{report["device"]} ({report["platform"]}), jax {report["jax_version"]}: {report["command"]}')
  print(TABLE_HEAD, flush=True)
  for name in names:  # Rows printed as each precision finishes.
    report['results'][name] = measure_precision(name, methods, args, bindings)
    print(table_rows(name, report['results'][name]), flush=True)
  gin.clear_config()
  if args.out:
    with open(args.out, 'w') as f:
      json.dump(report, f, indent=2)


if __name__ == '__main__':
  sys.exit(cli.run(main))
