"""Runs a study or a paper table: every cell (method x scene x axis points) trained and evaluated in its own run.

Usage: python -m lab.study STUDY.toml [--out out/studies] [--data_root data] [--jobs N] [--gpus 0,1,...]
                             [--shard K/N] [--executor local|ray [--address A] [--num-gpus G] [--num-cpus C]
                             [--max-retries R]] [--list [--estimate [--cluster-gpus N]]] [--plots-only]
                             [--gin_bindings B ...] [--export DIR] [--reuse DIR]

Each cell runs `train(config)` then eval's `evaluate(config)` in a subprocess (`python -m lab.study
--run-cell <cell dir>`: gin state stays per process and cells can run in parallel) in the run directory
<out>/<study>/<cell id>/run/, and writes <out>/<study>/<cell id>/cell.json: the evaluation means, wall times (train, eval; they
include data loading and compilation), steps/s, XLA's flop count of one train step, the process's peak RSS
and, on accelerators, the device's peak bytes. Its output goes to <cell>/log.txt. A study's [evaluations.<name>]
evaluate each finished cell again under bookkeeping settings, into <cell>/evaluations/<name>/ (results.csv columns
<metric>@<name>; lab/study/evaluations.py).
Resumable: a cell with cell.json is skipped; a half-trained one resumes from its newest checkpoint. A cell process
claims its cell first (lab/study/claim.py), so any number of runners may share a study folder. --reuse DIR
takes the finished cells of an earlier export (another machine's, say) instead of running them again; --export DIR
writes one: results, plots, pictures and cells.jsonl, a line per cell (lab/study/export.py, cells_file.py).
--jobs N runs N cells at a time; --gpus gives one GPU per worker (CUDA_VISIBLE_DEVICES), --shard K/N takes
every N-th cell from K (one command per host on a shared folder); --executor ray runs the cells as Ray tasks
(lab/study/ray_executor.py, docs/cluster.md). At the end (also after failures) the
results of all finished cells are gathered into <out>/<study>/results.csv and <metric>_vs_<x>.png plots, and
the cells' learning curves (Config.curve_every > 0) into psnr_vs_step.png (and psnr_masked_vs_step.png on DTU).
`python -m tools.tables <out>/<study>` gathers the same runs into the paper's tables.
With seeds (a `seeds` key or an axis named seed) results also give per cell the mean, spread and n over seeds and
the paired comparisons with their 95% intervals, corrected for the seed counts at which they were read
(lab/study/stats.py, looks.py). `--list --estimate` measures each distinct
setting of the pending cells on this machine (about a minute each) and prints the expected wall time before any
cell runs (lab/study/estimate.py); with --cluster-gpus N, the GPU-hours and the wall time on N GPUs from the step
times measured on a GPU (results/gpu). Bad input is one line (exit status 2, internal/cli.py).
"""

import argparse
import csv
import dataclasses
import io
import json
import os
import resource
import signal
import subprocess
import sys
import time
import warnings
from typing import Dict, List, Optional

from internal import atomic
from internal import cli
from internal import runs
from tools import provenance
from lab.study import time_budgets
from lab.study import cells_file
from lab.study import claim
from lab.study import estimate
from lab.study import evaluations
from lab.study import export
from lab.study import looks
from lab.study import plots
from lab.study import reuse
from lab.study import dispatch
from lab.study import spec
from lab.study import stats

CELL_FILE = 'cell.json'
LOG_FILE = dispatch.LOG_FILE
RUN_SUBDIR = export.RUN_SUBDIR  # The cell's run directory (Config.checkpoint_dir) inside its folder.
RESULTS_FILE = 'results.csv'
SUMMARY_FILE = 'summary.csv'          # Per cell pooled over seeds: mean, std, n of each plotted metric.
COMPARISONS_FILE = 'comparisons.csv'  # The paired comparisons with their intervals and verdicts.
COMPARISONS_MD = 'comparisons.md'
REPO = dispatch.REPO
TERMINATED_MESSAGE = ('terminated: stopped by SIGTERM before the command finished; its cells saved their checkpoints, '
                      'what it wrote is kept, and the same command run again finishes the work')


def study_dir(study: spec.Study, out: str) -> str:
  return os.path.join(out, study.name)


def cell_dir(study: spec.Study, cell: spec.Cell, out: str) -> str:
  return os.path.join(study_dir(study, out), cell.cell_id)


def read_cell(path: str) -> Optional[dict]:
  """The cell.json of a cell folder, or None when the cell has not finished; ValueError naming a malformed one (not
  JSON, or without the final step its run reached)."""
  path = os.path.join(path, CELL_FILE)
  if not os.path.isfile(path):
    return None
  record = cells_file.read_json(path)
  if not isinstance(record, dict) or not isinstance(record.get('step'), int):
    raise ValueError(f'{path}: a finished cell\'s record names its final step ("step": an integer); found none')
  return record


def write_spec(study: spec.Study, cell: spec.Cell, out: str, data_root: str, extra_bindings=()) -> str:
  """Writes <cell>/cell_spec.json (the cell's gin configs and bindings, labels), atomically and never for a
  finished cell (its spec records what ran), and the evaluations the study asks of it; returns the cell folder."""
  path = cell_dir(study, cell, out)
  os.makedirs(path, exist_ok=True)
  evaluations.write_wanted(path, dict(study.evaluations))
  if not os.path.isfile(os.path.join(path, CELL_FILE)):
    spec.write_cell_spec(path, study, cell, spec.cell_gin(study, cell, out, data_root, os.path.join(path, RUN_SUBDIR),
                                                          extra_bindings))
  return path


def has_run(path: str, record: dict) -> bool:
  """Whether a finished cell's folder holds its final checkpoint (a cell taken from an export has none)."""
  return runs.latest_step(os.path.join(path, RUN_SUBDIR)) == record['step']


def is_finished(path: str) -> bool:
  """Whether a cell is trained and evaluated as the study asks (its further evaluations too, where its run is here)."""
  record = read_cell(path)
  return record is not None and not (evaluations.missing(path, record['step']) and has_run(path, record))


def stale_cells(study: spec.Study, done: list, out: str, data_root: str, extra_bindings=()) -> Dict[str, str]:
  """{cell folder: the settings that differ} of the finished (cell, folder) pairs in done whose run trained with other
  settings than the study gives the cell now (a study or gin file edited after it ran), the precision aside (each
  machine resolves 'default' to its own); a cell taken from an export (--reuse) has no run to compare."""
  stale = {}
  for cell, path in done:
    stored = runs.read_fingerprint(os.path.join(path, RUN_SUBDIR))
    if stored is None:
      continue
    files_and_bindings = spec.cell_gin(study, cell, out, data_root, os.path.join(path, RUN_SUBDIR), extra_bindings)
    with warnings.catch_warnings():  # A setting's warnings are the cell's to print when it runs, not once a cell.
      warnings.simplefilter('ignore')
      with runs.fresh_config(*files_and_bindings) as config:  # The model's settings (MLP.*, ...): gin, bound here.
        differences = runs.differences({**stored, 'Config.precision': config.precision}, config)
    if differences:
      stale[path] = differences
  return stale


def check_not_stale(study: spec.Study, done: list, out: str, data_root: str, extra_bindings=()) -> None:
  """StudyError naming each finished cell that trained with other settings than the study gives it now."""
  stale = stale_cells(study, done, out, data_root, extra_bindings)
  if stale:
    listed = '; '.join(f'{path} ({differences})' for path, differences in stale.items())
    raise spec.StudyError(f'{study.path}: {len(stale)} finished cell(s) trained with other settings than the '
                                f'study gives them now: {listed}. Their results are not this study\'s: move those '
                                'cell folders away to train them again, or restore the settings they ran with')


def _publish(path: str, record: dict) -> None:
  """Writes <path>/cell.json, complete when it appears; FileExistsError instead of replacing a finished cell's."""
  tmp = os.path.join(path, f'{CELL_FILE}.{os.getpid()}.tmp')
  atomic.write_text(tmp, json.dumps(record, indent=1))
  try:
    os.link(tmp, os.path.join(path, CELL_FILE))
  finally:
    os.remove(tmp)


class CellStopped(Exception):
  """A signal stopped the cell's training (its checkpoint saved); the study run again resumes it."""

  def __init__(self, signum: int, step: int):
    super().__init__(f'stopped by signal {signum} at step {step} with a checkpoint saved; the study run again '
                     'resumes it')
    self.signum = signum


class Terminated(KeyboardInterrupt):
  """SIGTERM to the study command: its cells stop as on Ctrl-C (dispatch.run cancels them on a KeyboardInterrupt)."""


def _raise_terminated(signum, frame):
  del signum, frame
  raise Terminated()


def _peak_memory() -> dict:
  """Peak RSS of this process (MiB) and the first device's peak bytes in use (None where not reported)."""
  import jax  # pylint: disable=import-outside-toplevel
  memory = jax.local_devices()[0].memory_stats() or {}
  return {'peak_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.,
          'device_peak_bytes': memory.get('peak_bytes_in_use')}


def run_cell(path: str, job: str, stop=None) -> Optional[dict]:
  """Claims the cell in folder path for job (claim.Held if another job holds it), then trains (resuming) and
  evaluates it from its cell_spec.json and writes cell.json; None when another runner had finished it. stop: the
  runs.stop_flag() that training records its signals in (default: its own)."""
  with claim.claimed(path, job):
    record = read_cell(path)
    trained = record is None
    if trained:
      record = _train_and_evaluate(path, stop)
    if has_run(path, record):
      evaluations.run_missing(path, record['step'], lambda extra: spec.cell_config(path, extra))
    return record if trained else None


def _train_and_evaluate(path: str, stop) -> dict:
  """Trains (resuming; signals recorded in stop) and evaluates the cell in folder path from its cell_spec.json;
  writes cell.json."""
  commit, changed = provenance.code_state(REPO)  # The code it starts with.
  cell_spec = spec.read_cell_spec(path)
  with spec.cell_config(path) as config:
    start_step = runs.latest_step(config.checkpoint_dir)
    tic = time.perf_counter()
    result = runs.train(config, stop)
    train_seconds = time.perf_counter() - tic
    if result.signum is not None:
      raise CellStopped(result.signum, int(result.state.step))
    tic = time.perf_counter()
    record = runs.evaluate(config)
    eval_seconds = time.perf_counter() - tic
    gflops = runs.step_flops(config) / 1e9
  steps = config.max_steps - (start_step or 0)
  cell = {**{k: cell_spec[k] for k in ('study', 'cell', 'method', 'scene', 'labels')},
          'dataset': record['dataset'], 'record_scene': record['scene'], 'n_input_views': record['n_input_views'],
          'expname': config.expname, 'step': record['step'], 'complete': record['complete'],
          'means': record['means'], 'resumed_from_step': start_step, 'steps_trained': steps,
          'train_seconds': train_seconds, 'eval_seconds': eval_seconds,
          'steps_per_sec': steps / train_seconds if steps else None,
          'gflops_per_step': gflops, **_peak_memory(),
          'commit': commit, 'changed_files': changed, 'machine': provenance.machine()}
  _publish(path, cell)
  return cell


def measure_cell(path: str) -> dict:
  """The estimated {'train', 'eval'} seconds of the cell in folder path, measured on this machine."""
  with spec.cell_config(path) as config:
    return estimate.cell_seconds(config, estimate.measure(config))


def measured_estimates(paths: List[str]) -> List[tuple]:
  """(path, {'train', 'eval'} seconds) of each cell folder; one measuring process per distinct setting."""
  known, estimates = {}, []
  for path in paths:
    key = estimate.signature(spec.read_cell_spec(path))
    if key not in known:
      print(f'measuring {path} ...', flush=True)
      result = subprocess.run([sys.executable, '-m', 'lab.study', '--measure-cell', path], capture_output=True,
                              text=True, env={**os.environ, 'PYTHONPATH': dispatch.python_path()},
                              check=False)
      if result.returncode:
        raise RuntimeError(f'measuring {path} failed: {result.stderr.strip().splitlines()[-1:]}')
      known[key] = json.loads(result.stdout.strip().splitlines()[-1])
    estimates.append((path, known[key]))
  return estimates


def _list(study: spec.Study, args) -> None:
  """--list: each cell's state (and measured times when done); with --estimate the pending cells' expected times
  (with --cluster-gpus on GPUs, from results/gpu, instead of the state lines)."""
  pending, lines = [], []
  for cell in spec.cells(study):
    path, record = cell_dir(study, cell, args.out), read_cell(cell_dir(study, cell, args.out))
    if record:
      lines.append(f'done    {path}  (took {estimate.format_duration(record["train_seconds"] + record["eval_seconds"])})')
    else:
      lines.append(f'pending {path}')
      pending.append(cell)
  if args.cluster_gpus:
    print(f'{study.path}: {len(pending)} pending cell(s) estimated, {len(lines) - len(pending)} done not counted')
    print('\n'.join(estimate.cluster_lines([(c.cell_id, c.method, _gpu_config(study, c, args)) for c in pending],
                                            *estimate.device_bench(args.device_bench), args.cluster_gpus)))
    return
  print('\n'.join(lines))
  if args.estimate and pending:
    paths = [write_spec(study, c, args.out, args.data_root, tuple(args.gin_bindings)) for c in pending]
    print('\n'.join(estimate.summary_lines(measured_estimates(paths), args.jobs)))


def _gpu_config(study: spec.Study, cell: spec.Cell, args):
  """The validated Config of a cell as a GPU runs it (Config.precision 'auto' is bfloat16 there; nothing is
  written)."""
  run_dir = os.path.join(cell_dir(study, cell, args.out), RUN_SUBDIR)
  files_and_bindings = spec.cell_gin(study, cell, args.out, args.data_root, run_dir, tuple(args.gin_bindings))
  with runs.fresh_config(*files_and_bindings, backend='gpu') as config:
    return config


def _worker_envs(jobs: int, gpus: Optional[str]) -> List[Dict[str, str]]:
  """One environment per worker: its GPU when --gpus is given."""
  if gpus:
    return [{'CUDA_VISIBLE_DEVICES': g.strip()} for g in gpus.split(',')]
  return [{} for _ in range(jobs)]


def _run_in_process(paths: List[str], job: str) -> Dict[str, str]:
  """Runs the cells of paths one after another in this process (tests); returns {path: error} of failed cells."""
  failed = {}
  for path in paths:
    try:
      run_cell(path, job)
    except Exception as e:  # pylint: disable=broad-except  (one failed cell must not stop the study)
      failed[path] = f'{type(e).__name__}: {e}'
  return failed


def _shard(cells: list, shard: Optional[str]) -> list:
  """Every N-th cell from K for --shard K/N."""
  if not shard:
    return cells
  try:
    k, n = map(int, shard.split('/'))
  except ValueError:
    raise ValueError(f'--shard {shard!r}; expected K/N with 0 <= K < N') from None
  if not 0 <= k < n:
    raise ValueError(f'--shard {shard!r}; expected K/N with 0 <= K < N')
  return cells[k::n]


def gather(study: spec.Study, out: str) -> List[dict]:
  """Rows of results.csv: one per cell (finished or not), labels, status, means and costs."""
  rows = []
  for cell in spec.cells(study):
    record = read_cell(cell_dir(study, cell, out))
    row = {'cell': cell.cell_id, 'method': cell.method, 'scene': cell.scene, **cell.labels(),
           'status': 'done' if record else 'missing'}
    if record:
      row.update(step=record['step'], complete=record['complete'], **record['means'],
                 **{k: record[k] for k in ('train_seconds', 'eval_seconds', 'steps_trained', 'steps_per_sec',
                                           'gflops_per_step', 'peak_rss_mb', 'device_peak_bytes')},
                 **evaluations.columns(cell_dir(study, cell, out), record['step'], dict(study.evaluations)))
    rows.append(row)
  return rows


def gather_curves(study: spec.Study, out: str) -> List[dict]:
  """Rows of the cells' learning curves (where recorded): per cell and curve step, its labels and values."""
  rows = []
  for cell in spec.cells(study):
    path = runs.curve_path(os.path.join(cell_dir(study, cell, out), RUN_SUBDIR))
    rows += [{'method': cell.method, 'scene': cell.scene, **cell.labels(), **row} for row in runs.read_curve(path)]
  return rows


def _write_csv(path: str, rows: List[dict]) -> str:
  """Writes rows (dicts; None as empty) to path as CSV with the union of their keys; returns path."""
  fields = list(dict.fromkeys(k for row in rows for k in row))
  text = io.StringIO()
  writer = csv.DictWriter(text, fieldnames=fields)
  writer.writeheader()
  writer.writerows({k: ('' if row.get(k) is None else row.get(k)) for k in fields} for row in rows)
  os.makedirs(os.path.dirname(path), exist_ok=True)
  atomic.write_text(path, text.getvalue())
  return path


def _number(value, digits: int = 3) -> str:
  return '' if value is None else f'{value:.{digits}f}'


def comparisons_markdown(study: spec.Study, comparisons: List[stats.Comparison]) -> str:
  """The intervals' level and looks (looks.describe), then the comparisons as a Markdown table: a - b, n,
  mean, interval, verdict (undecided ones in bold)."""
  level = stats.level_text(stats.look_level(study))
  lines = [looks.describe(study), '', f'| metric | a - b | n | mean | {level} interval | verdict |',
           '|---|---|---|---|---|---|']
  for c in comparisons:
    verdict = f'**{c.verdict}**' if c.verdict.startswith(stats.UNDECIDED) else c.verdict
    interval = f'[{_number(c.low)}, {_number(c.high)}]' if c.low is not None else 'none'
    lines.append(f'| {c.metric} | {c.a} - {c.b} ({c.axis}) | {c.n} | {_number(c.mean)} | {interval} | {verdict} |')
  return '\n'.join(lines) + '\n'


def write_statistics(study: spec.Study, rows: List[dict], out_dir: str) -> List[str]:
  """summary.csv (per cell over seeds: mean, std, n) and the comparisons (CSV, Markdown); the written paths."""
  summary = [s for metric in study.plot.metrics for s in stats.summarize(study, rows, metric)]
  comparisons = [c for metric in study.plot.metrics for c in stats.compare(study, rows, metric)]
  written = [_write_csv(os.path.join(out_dir, SUMMARY_FILE), summary)] if summary else []
  if comparisons:
    written.append(_write_csv(os.path.join(out_dir, COMPARISONS_FILE), [c.row() for c in comparisons]))
    with open(os.path.join(out_dir, COMPARISONS_MD), 'w') as f:
      f.write(comparisons_markdown(study, comparisons))
    written.append(os.path.join(out_dir, COMPARISONS_MD))
  return written


def write_results(study: spec.Study, out: str) -> List[str]:
  """Writes results.csv, the statistics over seeds and the plots (learning curves too, where recorded);
  returns the written paths."""
  rows, curve_rows = gather(study, out), gather_curves(study, out)
  out_dir = study_dir(study, out)
  looks.record_if_finished(study, out_dir, rows)
  study = looks.with_recorded(study, out_dir)  # Every interval corrected for the looks (lab/study/looks.py).
  path = _write_csv(os.path.join(out_dir, RESULTS_FILE), rows)
  return ([path] + write_statistics(study, rows, out_dir) + plots.write_plots(study, rows, out_dir)
          + plots.write_curve_plots(study, curve_rows, out_dir)
          + time_budgets.write_budget_results(study, curve_rows, out_dir, plots.CURVE_METRICS))


def run_study(study: spec.Study, out: str, data_root: str = 'data', shard: Optional[str] = None,
              executor=None, job: Optional[str] = None, extra_bindings=()) -> Dict[str, str]:
  """Runs the unfinished cells (of the shard) on executor (None: in this process), each claimed for job, then
  writes results and plots; returns {cell dir: error}."""
  cells = _shard(spec.cells(study), shard)
  paths = [write_spec(study, c, out, data_root, extra_bindings) for c in cells]
  check_not_stale(study, [(c, p) for c, p in zip(cells, paths) if read_cell(p) is not None], out, data_root,
                  extra_bindings)
  _warn_unevaluable(paths)
  todo = [p for p in paths if not is_finished(p)]
  job = job or dispatch.new_job()
  if executor is None:
    failed = _run_in_process(todo, job)
  else:
    failed = dispatch.run(todo, executor, is_finished) if todo else {}
  with claim.claimed(study_dir(study, out), job, wait=True):  # One runner at a time writes the results.
    for path in write_results(study, out):
      print(path)
  return failed


def _warn_unevaluable(paths: List[str]) -> None:
  """A warning per finished cell without its run here (taken from an export) that lacks an evaluation asked of it."""
  for path in paths:
    record = read_cell(path)
    lacking = record and not has_run(path, record) and evaluations.missing(path, record['step'])
    if lacking:
      print(f'warning: {path}: evaluations {sorted(lacking)} not run: the cell came without its checkpoints (from an '
            'export); its columns stay empty')


def _parser() -> argparse.ArgumentParser:
  parser = cli.FlagParser(prog='python -m lab.study', description=__doc__.split('\n')[0])
  parser.add_argument('study', nargs='?', help='study file (TOML)')
  parser.add_argument('--out', default='out/studies', help='root of the study folders')
  parser.add_argument('--data_root', default='data', help='fills {data_root} in the study file')
  parser.add_argument('--jobs', type=int, default=1, help='cells run at a time')
  parser.add_argument('--gpus', help='comma-separated GPU ids, one worker each (overrides --jobs)')
  parser.add_argument('--shard', help='K/N: run every N-th cell starting at K (one command per host)')
  parser.add_argument('--executor', choices=('local', 'ray'), default='local',
                      help='where cells run: processes on this machine, or Ray tasks (docs/cluster.md)')
  parser.add_argument('--address', help='with --executor ray: the Ray cluster (default: start a local one); '
                      'an address where no cluster answers within 10 s is an error')
  parser.add_argument('--num-gpus', type=float, help='with --executor ray: GPUs per cell ([resources] num_gpus)')
  parser.add_argument('--num-cpus', type=float, help='with --executor ray: CPUs per cell ([resources] num_cpus)')
  parser.add_argument('--max-retries', type=int, help='with --executor ray: retries of a cell whose worker or '
                      'node was lost ([resources] max_retries)')
  parser.add_argument('--list', action='store_true', help='list the cells and their state, run nothing')
  parser.add_argument('--estimate', action='store_true', help='with --list: measure each distinct setting of '
                      'the pending cells here (about a minute each) and print the expected wall time')
  parser.add_argument('--cluster-gpus', type=int, metavar='N', help='with --estimate: instead of measuring, the '
                      'GPU-hours and the wall time on N GPUs from the measured GPU step times (results/gpu)')
  parser.add_argument('--device-bench', metavar='FILE', help='with --cluster-gpus: the bench.device JSON to read '
                      '(default: the one results/gpu/bench_device_*.json)')
  parser.add_argument('--plots-only', action='store_true', help='only gather results.csv and the plots')
  parser.add_argument('--gin_bindings', action='extend', nargs='+', default=[], metavar='BINDING',
                      help='gin bindings appended to every cell (after the study file\'s own)')
  parser.add_argument('--export', metavar='DIR', help='after the run, copy results, plots, cells.jsonl (a line per '
                      'cell), side-by-side pictures and provenance (no checkpoints) into DIR, to be committed')
  parser.add_argument('--reuse', metavar='DIR', help='first take the finished cells of an earlier --export DIR '
                      'that this study lacks and runs with the same settings (lab/study/reuse.py)')
  parser.add_argument('--run-cell', metavar='CELL_DIR', help=argparse.SUPPRESS)
  parser.add_argument('--job', help=argparse.SUPPRESS)
  parser.add_argument('--measure-cell', metavar='CELL_DIR', help=argparse.SUPPRESS)
  return parser


def _check_flags(args) -> None:
  """ValueError naming the first flag that is out of range or does not go with the others."""
  ray_only = [f for f, v in (('--address', args.address), ('--num-gpus', args.num_gpus),
                             ('--num-cpus', args.num_cpus), ('--max-retries', args.max_retries)) if v is not None]
  checks = [
      (not args.study, 'a study file is required'),
      (args.jobs < 1, f'--jobs {args.jobs}; expected >= 1'),
      (args.executor != 'ray' and ray_only, f'{", ".join(ray_only)}: only with --executor ray'),
      (args.executor == 'ray' and (args.jobs != 1 or args.gpus), '--jobs and --gpus are the local executor\'s; with '
       '--executor ray each cell asks for [resources] (or --num-gpus / --num-cpus) and Ray places it'),
      (any(v is not None and not 0 <= v < float('inf') for v in (args.num_gpus, args.num_cpus, args.max_retries)),
       '--num-gpus, --num-cpus and --max-retries must be >= 0'),
      (args.estimate and not args.list, '--estimate goes with --list'),
      (args.cluster_gpus is not None and not args.estimate, '--cluster-gpus goes with --list --estimate'),
      (args.cluster_gpus is not None and args.cluster_gpus < 1, f'--cluster-gpus {args.cluster_gpus}; expected >= 1'),
      (args.device_bench and args.cluster_gpus is None, '--device-bench goes with --cluster-gpus'),
      (args.export and os.path.isdir(args.export) and os.listdir(args.export),
       f'--export {args.export}: the folder exists and is not empty; export into a new folder (or delete that one) '
       'so that earlier results are not overwritten'),
      (args.reuse and args.gin_bindings, '--reuse matches cells by the study file\'s settings, and an export does '
       'not record --gin_bindings: put those bindings in the study file'),
  ]
  for failed, message in checks:
    if failed:
      raise ValueError(message)
  _shard([], args.shard)


def _resources(study: spec.Study, args) -> spec.Resources:
  """The study file's [resources], with the flags that override them."""
  flags = {'num_gpus': args.num_gpus, 'num_cpus': args.num_cpus, 'max_retries': args.max_retries}
  return dataclasses.replace(study.resources, **{k: v for k, v in flags.items() if v is not None})


def _executor(study: spec.Study, args, job: str):
  """The executor of --executor: processes here (--jobs / --gpus), or Ray tasks with the cells' resources."""
  if args.executor == 'ray':
    from lab.study import ray_executor  # pylint: disable=import-outside-toplevel  (Ray is an optional extra)
    return ray_executor.RayExecutor(args.address, _resources(study, args), job)
  return dispatch.LocalExecutor(_worker_envs(args.jobs, args.gpus), job)


def _run_one_cell(path: str, job: Optional[str]) -> int:
  """--run-cell: the cell process; CLAIMED_STATUS when a runner of another job holds the cell.

  One signal stops it: SIGINT or SIGTERM before training is a KeyboardInterrupt (the claim released, one line),
  during training the loop saves a checkpoint and stops, and once that signal stopped training further ones (Ray,
  the claim's stop request, the runner and the user may all ask) are ignored while the cell saves, releases its
  claim and exits.
  """
  stop = runs.stop_flag()
  for signum in (signal.SIGINT, signal.SIGTERM):
    signal.signal(signum, stop.raise_unless_stopped)
  dispatch.stop_with_runner()
  try:
    record = run_cell(path, job or dispatch.new_job(), stop)
  except claim.Held as e:
    print(f'not run: {e}')
    return dispatch.CLAIMED_STATUS
  except CellStopped as e:
    for signum in (signal.SIGINT, signal.SIGTERM):  # Ignored to its end (Python's exit resets its own handlers).
      signal.signal(signum, signal.SIG_IGN)
    print(f'{path}: {e}')
    return cli.signal_status(e.signum)
  print(json.dumps(record, indent=1) if record else f'{path} was trained already (here or by another runner); not '
        'trained again')
  return 0


def main(argv=None) -> int:
  """CLI entry point; returns the exit status (1 when a cell failed)."""
  args = _parser().parse_args(argv)
  if args.run_cell:
    return _run_one_cell(args.run_cell, args.job)
  if args.measure_cell:
    print(json.dumps(measure_cell(args.measure_cell)))
    return 0
  _check_flags(args)
  study = spec.load(args.study)
  if args.reuse:
    reuse.reuse(study, args.reuse, study_dir(study, args.out), args.data_root)
  if args.list:
    _list(study, args)
    return 0
  if args.plots_only:
    for path in write_results(study, args.out):
      print(path)
    _export(study, args, argv)
    return 0
  try:
    failed = _run_on_executor(study, args)
  except Terminated:
    print(TERMINATED_MESSAGE, file=sys.stderr)
    return cli.signal_status(signal.SIGTERM)
  for path, error in failed.items():
    print(f'FAILED {path}: {error}', file=sys.stderr)
  _export(study, args, argv)
  return 1 if failed else 0


def _run_on_executor(study: spec.Study, args) -> Dict[str, str]:
  """Runs the study's cells on the executor of the flags; returns {cell dir: error}. SIGTERM meanwhile stops the
  cells as Ctrl-C does (Terminated), its handler set once the executor is made: Ray's (sys.exit) would leave the
  running cells behind."""
  job, before = dispatch.new_job(), signal.getsignal(signal.SIGTERM)
  executor = _executor(study, args, job)
  try:
    signal.signal(signal.SIGTERM, _raise_terminated)
    return run_study(study, args.out, args.data_root, args.shard, executor, job, tuple(args.gin_bindings))
  finally:
    executor.close()
    signal.signal(signal.SIGTERM, before)


def _export(study: spec.Study, args, argv) -> None:
  """--export: copies the study's results into args.export, recording this command."""
  if args.export:
    command = cli.command_line('lab.study', argv)
    for path in export.export(study, args.study, study_dir(study, args.out), args.export, command):
      print(path)

