"""A study's cost before it runs: each distinct cell setting is measured on this machine (data loading and
compilation, the median of a few train steps, one test view rendered) and scaled to the cell's steps, learning
curve and evaluation.

The estimate counts training steps, the learning curve's renders and the evaluation's renders; it leaves out
checkpoint writes and the metrics themselves (LPIPS), so expect the real time to be somewhat longer.
"""

import json
import statistics
import time
from typing import Dict, List

from tools import study_spec

PROBE_STEPS = 6  # Timed train steps after the first (compiling) one.


def signature(spec: dict) -> str:
  """What decides a cell's cost: its gin configs and bindings without the seeds, run folder and name."""
  skip = study_spec.SEED_BINDINGS + ('Config.checkpoint_dir', 'Config.expname')
  bindings = [b for b in spec['gin_bindings'] if b.split('=')[0].strip() not in skip]
  return json.dumps([spec['gin_configs'], bindings])


def _timed(fn):
  """(fn()'s result with every array ready, seconds it took)."""
  import jax  # pylint: disable=import-outside-toplevel
  tic = time.perf_counter()
  result = jax.block_until_ready(fn())
  return result, time.perf_counter() - tic


def measure(config) -> Dict[str, float]:
  """{'setup_seconds' (data, model, first step with compilation), 'step_seconds' (median of PROBE_STEPS),
  'view_seconds' (one test view at Config.eval_factor, compiled), 'eval_views', 'curve_views'} of a config."""
  # pylint: disable=import-outside-toplevel  (jax and the model only in the measuring process)
  import jax
  from jax import random
  from internal import datasets
  from internal.evaluation import evaluate, inference
  from internal.run import sharding
  from internal.training import train_step
  tic = time.perf_counter()
  batcher = datasets.make_batcher(datasets.load_dataset('train', config), config)
  mesh = sharding.data_mesh()
  model, state = train_step.create_train_state(config, random.PRNGKey(config.jax_rng_seed),
                                               jax.tree.map(lambda x: x[:8], batcher(0)['rays']))
  state, step_fn, key = sharding.replicate(state, mesh), train_step.make_train_step(config, model), random.PRNGKey(0)
  batch = lambda step: sharding.shard_batch(batcher(step), mesh)
  state, _ = _timed(lambda: step_fn(state, batch(1), key))[0]
  setup = time.perf_counter() - tic
  times = []
  for step in range(2, 2 + PROBE_STEPS):
    (state, _), seconds = _timed(lambda s=step: step_fn(state, batch(s), key))
    times.append(seconds)
  test_set = datasets.load_dataset('test', config)
  render_fn = inference.make_render_fn(config, model, sharding.local_copy(state.params), PROBE_STEPS + 1)
  view = jax.tree.map(lambda x: x[0], test_set.rays)
  render = lambda: inference.render_image(render_fn, view, config.render_chunk_size)
  _timed(render)
  curve_views = len(config.curve_test_ids) if config.curve_every else 0
  return {'setup_seconds': setup, 'step_seconds': statistics.median(times), 'view_seconds': _timed(render)[1],
          'eval_views': len(evaluate.select_positions(config, len(test_set.ids))), 'curve_views': curve_views}


def cell_seconds(config, measured: Dict[str, float]) -> Dict[str, float]:
  """{'train', 'eval'} seconds estimated for a cell of config from the measurement of its setting."""
  curve_points = config.max_steps // config.curve_every if config.curve_every else 0
  curve_scale = (config.eval_factor / config.curve_factor) ** 2  # Pixels of a curve view per evaluated pixel.
  train = (measured['setup_seconds'] + config.max_steps * measured['step_seconds']
           + curve_points * measured['curve_views'] * measured['view_seconds'] * curve_scale)
  return {'train': train, 'eval': measured['eval_views'] * measured['view_seconds']}


def format_duration(seconds: float) -> str:
  """'1 h 05 min', '12 min' or '40 s'."""
  if seconds >= 3600:
    return f'{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min'
  return f'{seconds / 60:.0f} min' if seconds >= 60 else f'{seconds:.0f} s'


def summary_lines(estimates: List[tuple], jobs: int) -> List[str]:
  """Lines of the estimate: per cell (path, {'train', 'eval'}) and the total, sequential and per --jobs."""
  lines = [f'estimate {format_duration(e["train"] + e["eval"]):>12}  (train {format_duration(e["train"])}, '
           f'eval {format_duration(e["eval"])})  {path}' for path, e in estimates]
  total = sum(e['train'] + e['eval'] for _, e in estimates)
  lines.append(f'total for {len(estimates)} pending cell(s): {format_duration(total)} one after another'
               + (f'; with --jobs {jobs} at best {format_duration(total / jobs)} if the cores are free'
                  if jobs > 1 else ''))
  return lines
