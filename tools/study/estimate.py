"""A study's cost before it runs, two ways.

Here: each distinct cell setting is measured on this machine (data loading and compilation, the median of a few
train steps, one test view rendered) and scaled to the cell's steps, learning curve and evaluation. The estimate
counts training steps, the learning curve's renders and the evaluation's renders; it leaves out checkpoint writes
and the metrics themselves (LPIPS), so expect the real time to be somewhat longer.

On a cluster (`--cluster-gpus N`): nothing is measured; each cell's steps are multiplied by the train step time
that bench.device measured on a GPU at the precision the cell runs at there (Config.precision 'auto' resolved for
a GPU: bfloat16, whatever machine prints the estimate; results/gpu/bench_device_*.json), for the cell's method and
scaled to its rays per step. RegNeRF, when that benchmark did not time it, costs mip-NeRF's step times RegNeRF's
ratio to it: as a GPU window timed it (GPU_RATIO_GLOB, written by bench/lease.sh), else as
measured on a CPU (CPU_RATIO_FILE), and says which; another unmeasured method costs the mean of the measured ones.
The benchmark ran the paper's model, so the estimate holds for cells of that model; it counts training steps only
(no compilation, checkpoints, learning curves or evaluation), one GPU per cell, and packs the cells longest first
onto N GPUs.
"""

import glob
import heapq
import json
import os
import statistics
import time
from typing import Dict, List, Optional, Tuple

from tools import provenance
from tools.study import cells_file
from tools.study import spec as study_spec

PROBE_STEPS = 6  # Timed train steps after the first (compiling) one.
BENCH_GLOB = os.path.join('results', 'gpu', 'bench_device_*.json')  # bench.device's GPU records, in the repository.
# bench.device's records of RegNeRF's step beside mip-NeRF's: timed in GPU windows, and on a CPU.
GPU_RATIO_GLOB = os.path.join('results', 'gpu', 'ledger', 'variants', '*', 'bench_device.json')
CPU_RATIO_FILE = os.path.join('results', 'cluster', 'bench_device_cpu_regnerf.json')
REPO = study_spec.REPO


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
                                               jax.tree.map(lambda x: x[:8], batcher(0).rays))
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


def device_bench(path: Optional[str] = None) -> Tuple[str, dict]:
  """(path, record) of the bench.device JSON to estimate from: path, or the one file of BENCH_GLOB."""
  if path is None:
    found = sorted(glob.glob(os.path.join(REPO, BENCH_GLOB)))
    if len(found) != 1:
      raise ValueError(f'--cluster-gpus reads the GPU step times of {BENCH_GLOB}: found {len(found)} files '
                       f'{[os.path.basename(f) for f in found]}; expected one, or name it with --device-bench FILE')
    path = found[0]
  if not os.path.isfile(path):
    raise ValueError(f'--device-bench {path}: no such file; expected a JSON written by python -m bench.device')
  record = cells_file.read_json(path)
  if not isinstance(record.get('results'), dict) or not isinstance(record.get('batch_size'), int):
    raise ValueError(f'--device-bench {path}: no results per precision or batch_size; expected a JSON written by '
                     'python -m bench.device')
  return path, record


def gpu_step_seconds(bench: dict, precision: str, method: str, batch_size: int) -> Tuple[float, str]:
  """(seconds of a train step of method at precision on the benchmarked GPU for batch_size rays, a note saying
  what was not measured as such: another method, another batch)."""
  measured = bench['results'].get(precision)
  if not measured:
    raise ValueError(f'Config.precision {precision!r} has no GPU step time in the benchmark; it measured '
                     f'{sorted(bench["results"])}')
  methods = measured['methods']
  if method in methods:
    seconds, notes = methods[method]['step_seconds'], []
  elif method == 'regnerf' and 'mipnerf' in methods:
    ratio, where = regnerf_ratio(precision)
    seconds = methods['mipnerf']['step_seconds'] * ratio
    notes = [f"regnerf not benchmarked: mip-NeRF's step x {ratio:.2f}, {where}"]
  else:
    seconds = statistics.mean(m['step_seconds'] for m in methods.values())
    notes = [f'{method} not benchmarked: the mean of {", ".join(sorted(methods))}']
  if batch_size != bench['batch_size']:
    seconds *= batch_size / bench['batch_size']
    notes.append(f'batch {batch_size} scaled from {bench["batch_size"]}')
  return seconds, '; '.join(notes)


def _ratio(record: dict, precision: str) -> Optional[float]:
  """RegNeRF's step time over mip-NeRF's in a bench.device record, at precision or else its first precision timing
  both; None when it timed them at none."""
  both = [p for p, r in record.get('results', {}).items() if {'mipnerf', 'regnerf'} <= set(r.get('methods', {}))]
  if not both:
    return None
  methods = record['results'][precision if precision in both else both[0]]['methods']
  return methods['regnerf']['step_seconds'] / methods['mipnerf']['step_seconds']


def regnerf_ratio(precision: str) -> Tuple[float, str]:
  """(RegNeRF's step time over mip-NeRF's, where it was measured): the newest GPU window's that timed both, else
  the CPU's of CPU_RATIO_FILE."""
  timed = [(record.get('provenance', {}).get('date', ''), path, record) for path in
           glob.glob(os.path.join(REPO, GPU_RATIO_GLOB)) for record in [cells_file.read_json(path)]
           if _ratio(record, precision) is not None]
  if timed:
    _, path, record = max(timed, key=lambda found: found[:2])
    return _ratio(record, precision), f'as timed on {record.get("device")} ({os.path.relpath(path, REPO)})'
  path = os.path.join(REPO, CPU_RATIO_FILE)
  return _ratio(cells_file.read_json(path), precision), f'as measured on a CPU ({CPU_RATIO_FILE}), not yet on a GPU'


def wall_seconds(durations: List[float], gpus: int) -> float:
  """The wall time of cells of these durations on gpus GPUs, one cell each, the longest started first."""
  loads = [0.] * gpus
  for duration in sorted(durations, reverse=True):
    heapq.heappush(loads, heapq.heappop(loads) + duration)
  return max(loads, default=0.)


def cluster_lines(cells: List[Tuple[str, str, object]], bench_path: str, bench: dict, gpus: int) -> List[str]:
  """The cluster estimate of cells (cell id, method, Config): a line per cell, then per precision the GPU-hours
  and the wall time on gpus GPUs (the cells' own precisions first)."""
  lines = [f'GPU estimate from {os.path.relpath(bench_path, REPO)} ({bench.get("device")}, jax '
           f'{bench.get("jax_version")}) at commit {provenance.git_commit(REPO)}: training steps only, no '
           "compilation, checkpoints, learning curves or evaluation; one GPU per cell, at the precision it runs at "
           "on a GPU (Config.precision 'auto': bfloat16)"]
  own = []
  for cell_id, method, config in cells:
    step, note = gpu_step_seconds(bench, config.precision, method, config.batch_size)
    own.append(config.max_steps * step)
    lines.append(f'{own[-1] / 3600:8.2f} GPU-h  {config.max_steps} steps x {step * 1e3:.1f} ms '
                 f'({config.precision})  {cell_id}' + (f'  [{note}]' if note else ''))
  lines.append(_total_line('as configured', own, gpus))
  for precision in bench['results']:
    seconds = [c.max_steps * gpu_step_seconds(bench, precision, m, c.batch_size)[0] for _, m, c in cells]
    lines.append(_total_line(f'all at Config.precision = {precision!r}', seconds, gpus))
  return lines


def _total_line(label: str, seconds: List[float], gpus: int) -> str:
  return (f'total {label}: {len(seconds)} cell(s), {sum(seconds) / 3600:.1f} GPU-hours; on {gpus} GPU(s) '
          f'{format_duration(wall_seconds(seconds, gpus))} wall')
