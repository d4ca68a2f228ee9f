"""The train step at the scales people run on a CPU: its rate against the matmul rate, and where its time goes.

Usage: python -m bench.profile_step [--scales demo,mini,paper] [--repeats 7] [--profile_steps 5] [--out FILE]

Each scale is a gin setting of this project with random rays of its batch size (no data needed):
  demo   the demo's FreeNeRF (configs/demo.gin + demo_forward.gin: NeRF 4 x 64, 32 + 32 samples, 512 rays);
  mini   the CPU mini protocol's DTU FreeNeRF (configs/mini/dtu3_freenerf.gin: mip-NeRF 4 x 128, 2 x 32, 512 rays);
  paper  the paper's DTU FreeNeRF (configs/freenerf/dtu3_freenerf.gin: 8 x 256, 2 x 128 samples; batch 256).
Per scale, interleaved with two matmuls in the same run: the median step time, XLA's flop count of the compiled
step and the achieved GFLOP/s, against the best rate of the benchmark's matmuls (bench.released_comparison's
[4096 | 32768, 256] @ [256, 256]) and of the scale's own MLP matmul ([rays x samples, width] @ [width, width]),
and the time of the step's own matrix products run alone, one after another (what the step would take if all
else were free). Then a profiler trace of --profile_steps steps: every XLA operation's time is charged to a
stage by the source of the operation (the project file and function it was traced from; a fused operation by
its root).
"""

import argparse
import collections
import json
import os
import re
import sys

import jax
import jax.numpy as jnp
import numpy as np

from bench import common
from bench import kernel_profile
from bench import released_comparison
from internal import cli
from internal import rays as rays_lib
from internal.datasets import batching
from internal.models import registry

SCALES = {'demo': (cli.DEMO_CONFIGS, None),
          'mini': ([os.path.join(cli.CONFIG_DIR, 'mini', 'dtu3_freenerf.gin')], None),
          'paper': ([os.path.join(cli.CONFIG_DIR, 'freenerf', 'dtu3_freenerf.gin')], 256)}
PROJECT_FOLDERS = ('internal', 'bench', 'tools', 'tests')
# Stages by the module an operation was traced from (its path in the repository, or in site-packages for a
# library); the model's modules split into matmuls and the rest by operation.
FILE_STAGES = {'internal/models/encoding.py': 'encoding', 'internal/models/trig.py': 'encoding',
               'internal/models/gaussians.py': 'Gaussians of the samples',
               'internal/models/sampling.py': 'sampling and resampling',
               'internal/training/anneal.py': 'sampling and resampling',
               'internal/models/volume_render.py': 'volume rendering',
               'internal/models/freq_schedule.py': 'frequency masks',
               'internal/training/optim.py': 'clipping and Adam', 'internal/training/schedule.py': 'clipping and Adam'}
MODEL_FILES = ('internal/models/mip_nerf.py', 'internal/models/nerf.py', 'internal/models/dense.py',
               'internal/models/precision.py', 'internal/models/activations.py')
DIR_STAGES = {'internal/losses/': 'losses', 'optax/': 'clipping and Adam'}


def scale_config(name: str):
  """The validated Config of a scale (its gin files parsed now, replacing earlier bindings)."""
  files, batch_size = SCALES[name]
  return common.gin_config(files, ['MLP.density_noise = 1.0'], **({'batch_size': batch_size} if batch_size else {}))


def random_batch(config) -> batching.Batch:
  """A Batch of config.batch_size random rays between the config's near and far."""
  rays = common.dtu_like_rays(config.batch_size)
  bounds = jnp.ones_like(rays.near)
  rays = rays_lib.Rays(*rays[:-2], bounds * config.near, bounds * config.far)
  rgb = jnp.asarray(np.random.default_rng(1).uniform(size=(config.batch_size, 3)), jnp.float32)
  return batching.Batch(rays=rays, rgb=rgb)


def mlp_shape(config, model):
  """(rows, width) of the scale's MLP matmuls: rays x samples of the last level, the trunk width."""
  mlp = getattr(model, 'mlp', None) or model.fine_mlp
  return config.batch_size * model.fine_samples_per_ray(), mlp.net_width


def module_path(path: str) -> str:
  """A source file's path from this project's top folders (internal/, bench/, ...), or inside site-packages for a
  library's; else as given. By its parts, not by this checkout's location: a cached compilation keeps the paths
  of the checkout that compiled it."""
  parts = path.replace(os.sep, '/').split('/')
  if 'site-packages' in parts:
    return '/'.join(parts[len(parts) - parts[::-1].index('site-packages'):])
  top = next((i for i in range(len(parts) - 1, -1, -1) if parts[i] in PROJECT_FOLDERS), None)
  return '/'.join(parts[top:]) if top is not None else path


def source_table(hlo_text: str):
  """{stack frame id: (module_path of the file, function)} of the compiled module's location tables."""
  tables = collections.defaultdict(dict)
  section = None
  for line in hlo_text.splitlines():
    if line in ('FileNames', 'FunctionNames', 'FileLocations', 'StackFrames'):
      section = line
      continue
    match = re.match(r'(\d+) (.*)', line)
    if section and match:
      tables[section][int(match.group(1))] = match.group(2)
    elif line.strip():
      section = None
  files = {i: module_path(v.strip('"')) for i, v in tables['FileNames'].items()}
  functions = {i: v.strip('"') for i, v in tables['FunctionNames'].items()}

  def ids(text):
    return dict((k, int(v)) for k, v in re.findall(r'(\w+)=(\d+)', text))
  locations = {i: ids(v) for i, v in tables['FileLocations'].items()}
  return {i: (files[locations[f['file_location_id']]['file_name_id']],
              functions[locations[f['file_location_id']]['function_name_id']])
          for i, f in ((i, ids(v)) for i, v in tables['StackFrames'].items())}


def matmul_operations(hlo_text: str):
  """Names of the module's dot instructions and of the fusions whose computation holds a dot.

  Judged by content, not name: XLA's CPU backend also emits reductions (the bias gradients) as library fusions
  named like its matmuls.
  """
  with_dot = {match.group(1) for match in re.finditer(r'^%([\w.\-]+) \(.*?^\}', hlo_text, re.M | re.S)
              if re.search(r' dot\(', match.group(0))}
  names = set()
  for match in re.finditer(r'^\s*(?:ROOT )?%([\w.\-]+) = \S+ (dot|fusion)\(.*$', hlo_text, re.M):
    called = re.search(r'calls=%([\w.\-]+)', match.group(0))
    if match.group(2) == 'dot' or (called and called.group(1) in with_dot):
      names.add(match.group(1))
  return names


def module_dots(hlo_text: str):
  """Counter of the compiled module's matrix products: (lhs shape, rhs shape, dimension numbers) -> how many.

  Every float32 dot instruction (the scales run at float32), inside library fusions too, as XLA left it after
  optimization (a product it turned into element-wise work is not one); each runs once per step (the step's
  loops and branches hold none).
  """
  shapes = {name: tuple(int(d) for d in dims.split(',') if d) for name, dims in
            re.findall(r'%([\w.\-]+) = f32\[([\d,]*)\]', hlo_text)}
  dots = collections.Counter()
  for operands, numbers in re.findall(r'= f32\[[\d,]*\]\S* dot\(([^)]*)\), ((?:\w+_dims=\{[\d,]*\}, )+)', hlo_text):
    lhs, rhs = (shapes[name] for name in re.findall(r'%([\w.\-]+)', operands))
    dims = dict(re.findall(r'(\w+)_dims=\{([\d,]*)\}', numbers))
    axes = lambda key: tuple(int(d) for d in dims.get(key, '').split(',') if d)
    dimension_numbers = ((axes('lhs_contracting'), axes('rhs_contracting')), (axes('lhs_batch'), axes('rhs_batch')))
    dots[(lhs, rhs, dimension_numbers)] += 1
  return dots


def dots_alone_runner(dots):
  """Zero-arg callable: seconds to run every product of dots (module_dots) alone, as often as the step does."""
  calls = []
  for (lhs, rhs, dimension_numbers), count in dots.items():
    f = jax.jit(lambda a, b, n=dimension_numbers: jax.lax.dot_general(a, b, n, precision=jax.lax.Precision.HIGHEST))
    args = (jnp.ones(lhs, jnp.float32), jnp.ones(rhs, jnp.float32))
    common.block(f(*args))
    calls += [(f, args)] * count
  return lambda: common.timed(lambda: [common.block(f(*args)) for f, args in calls])


def operation_sources(hlo_text: str):
  """{operation name: (file, function, is a matmul)} of the compiled module's instructions."""
  frames = source_table(hlo_text)
  matmuls = matmul_operations(hlo_text)
  sources = {}
  for match in re.finditer(r'^\s*(?:ROOT )?%([\w.\-]+) = .*?stack_frame_id=(\d+)', hlo_text, re.M):
    name = match.group(1)
    sources[name] = frames.get(int(match.group(2)), ('?', '?')) + (name in matmuls,)
  return sources


def stage_of(source) -> str:
  """The stage an operation's (file, function, is a matmul) belongs to."""
  file, function, is_matmul = source
  if file in MODEL_FILES:
    return 'MLP matmuls' if is_matmul or function in ('matmul', 'matmuls', 'dense') else 'MLP activations and layout'
  if file in FILE_STAGES:
    return FILE_STAGES[file]
  folder = next((folder for folder in DIR_STAGES if file.startswith(folder)), None)
  if folder or 'loss' in function:
    return DIR_STAGES[folder] if folder else 'losses'
  return 'other (step glue)'


def traced_operation_times(run, steps: int):
  """{operation name: mean seconds per step} from a profiler trace of `steps` calls of run."""
  totals = collections.Counter()
  for event in kernel_profile.events(kernel_profile.record(run, steps)):
    totals[event['name']] += event.get('dur', 0) * 1e-6 / steps
  return totals


def breakdown(operation_times, sources):
  """{stage: seconds per step} of the traced operations of the step's module."""
  stages = collections.Counter()
  for name, seconds in operation_times.items():
    if name in sources:
      stages[stage_of(sources[name])] += seconds
  return dict(stages.most_common())


def measure(name: str, args):
  """The figures of one scale (see the module docstring)."""
  config = scale_config(name)
  batch = random_batch(config)
  model = registry.build(config.model, white_background=config.white_background)
  run, _, xla = common.step_runner(config, model, batch)
  rows, width = mlp_shape(config, model)
  runners = {'step': run,
             'matmul_bench': common.matmul_runner(released_comparison.MATMUL_SHAPES, min),
             'matmul_mlp': common.matmul_runner(((rows, width, width),), min),
             'dots_alone': dots_alone_runner(module_dots(xla['hlo']))}
  times = common.interleaved_medians(runners, args.repeats)
  achieved = xla['flops'] / times['step'] / 1e9
  rates = {key: 1 / times[key] / 1e9 for key in ('matmul_bench', 'matmul_mlp')}
  stages = breakdown(traced_operation_times(run, args.profile_steps), operation_sources(xla['hlo']))
  return {'gin': SCALES[name][0], 'batch': config.batch_size, 'step_ms': times['step'] * 1e3,
          'step_gflop': xla['flops'] / 1e9, 'achieved_gflops': achieved,
          'matmul_bench_gflops': rates['matmul_bench'], 'matmul_mlp_gflops': rates['matmul_mlp'],
          'mlp_matmul_shape': [rows, width, width],
          'of_matmul_bench': achieved / rates['matmul_bench'], 'of_matmul_mlp': achieved / rates['matmul_mlp'],
          'dots_alone_ms': times['dots_alone'] * 1e3, 'dots_alone_of_step': times['dots_alone'] / times['step'],
          'stage_ms': {stage: seconds * 1e3 for stage, seconds in stages.items()},
          'traced_ms': sum(stages.values()) * 1e3}


def table(results) -> str:
  """Markdown rows: the rate per scale, then each scale's stages in ms and share of the traced time."""
  lines = ['| scale | step ms | GFLOP | GFLOP/s | matmul GFLOP/s (bench / MLP shape) | of bench | of MLP shape | '
           'its matmuls alone ms (of step) |', '|---|---|---|---|---|---|---|---|']
  for name, r in results.items():
    lines.append(f"| {name} | {r['step_ms']:.1f} | {r['step_gflop']:.2f} | {r['achieved_gflops']:.1f} | "
                 f"{r['matmul_bench_gflops']:.0f} / {r['matmul_mlp_gflops']:.0f} | {r['of_matmul_bench']:.2f} | "
                 f"{r['of_matmul_mlp']:.2f} | {r['dots_alone_ms']:.1f} ({r['dots_alone_of_step']:.2f}) |")
  stages = list(dict.fromkeys(s for r in results.values() for s in r['stage_ms']))
  lines += ['', '| stage | ' + ' | '.join(f'{name} ms (share)' for name in results) + ' |',
            '|---|' + '---|' * len(results)]
  for stage in stages:
    cells = [f"{r['stage_ms'].get(stage, 0.):.1f} ({r['stage_ms'].get(stage, 0.) / r['traced_ms']:.0%})"
             for r in results.values()]
    lines.append(f'| {stage} | ' + ' | '.join(cells) + ' |')
  return '\n'.join(lines)


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--scales', default='demo,mini,paper', help=f'comma-separated, of {list(SCALES)}')
  parser.add_argument('--repeats', type=int, default=7)
  parser.add_argument('--profile_steps', type=int, default=5)
  parser.add_argument('--out', help='also write the figures as JSON here')
  args = parser.parse_args(argv)
  names = args.scales.split(',')
  unknown = sorted(set(names) - set(SCALES))
  if unknown:
    raise ValueError(f'--scales: unknown {unknown}; expected some of {list(SCALES)}')
  results = {name: measure(name, args) for name in names}
  print(table(results))
  if args.out:
    with open(args.out, 'w', encoding='utf-8') as f:
      json.dump({'devices': str(jax.devices()), 'jax': jax.__version__, 'scales': results}, f, indent=1)


if __name__ == '__main__':
  sys.exit(cli.run(main))
