"""Runs the demo for several seeds and records what it measured, per machine kind, to be committed: results/demo/.

  python -m tools.demo_seeds --seeds 20200823 1 [--out results/demo] [--work out/demo_seeds] [--gin_bindings B]

A seed is Config.jax_rng_seed (the models' initialization and sampling noise; 20200823, the default, is the demo's
own, run as plain `python train.py`). Per seed, each as its own process in <work>/seed_<seed>/, timed:
  the demo: `python train.py [--gin_bindings "Config.jax_rng_seed = <seed>"]`, both methods' test metrics;
  the all-views check (tests/test_demo.py): the demo's NeRF trained on every training view, evaluated without LPIPS.
A machine kind is the instruction set XLA compiles for (environment.cpu_isa: AVX512, AVX2, ...): float32 results
agree to the last digit only within a kind, so each kind has its own folder <out>/<kind>/ (XLA_FLAGS=
--xla_cpu_max_isa=AVX2 records the AVX2 kind's digits on an AVX-512 machine, its times then being this machine's).
Writes <out>/<kind>/seed_<seed>.json (the metrics, each method's learning curve (test PSNR of the curve views against
the step, as demo_curves.png draws it), the commands and their seconds, the load average before and after the demo
(other jobs on the machine slow it), provenance: commit, machine, date and this command), then <out>/<kind>/summary.json and README.md over every seed_*.json there: per seed and over the seeds
(mean, standard deviation, range) each method's PSNR, SSIM, LPIPS and depth error, FreeNeRF's lead, the all-views
PSNR and the wall times; and <out>/README.md, one line per kind. Before any work, the seeds are checked (whole
numbers, each once, seeds jax and numpy take), and a seed already recorded for this kind is refused, as is a work
folder already there (its times would not be a whole run). --gin_bindings adds bindings to every run (e.g. a
shorter schedule); the commands recorded show them.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import dataclasses
import glob
import json
import os
import subprocess
import sys
import time

from internal import atomic
from internal import cli
from internal import demo
from internal import environment
from internal.configs import Config
from internal.evaluation import evaluate
from internal.evaluation import learning_curve
from internal.evaluation import results
from tools import provenance
from tools.study import stats as study_stats

ROOT = provenance.ROOT
DEFAULT_SEED = next(f.default for f in dataclasses.fields(Config) if f.name == 'jax_rng_seed')
ALL_VIEWS = ['Config.n_input_views = 0', 'Config.compute_lpips = False', "Config.checkpoint_dir = 'out/all_views'"]
METRICS = ('psnr', 'ssim', 'lpips', 'depth_mae')  # The columns of each method's metrics.json means in the table.
SUMMARY, README = 'summary.json', 'README.md'


def kind_dir(out: str, kind: str = '') -> str:
  """<out>/<kind>: the records of one machine kind (this machine's by default)."""
  return os.path.join(out, kind or environment.cpu_isa())


def seed_file(out: str, seed: int) -> str:
  """A seed's record in a machine kind's folder."""
  return os.path.join(out, f'seed_{seed}.json')


def seed_bindings(seed: int, extra=()) -> list:
  """The extra bindings and those that set the seed (none for the demo's own)."""
  return list(extra) + ([] if seed == DEFAULT_SEED else [f'Config.jax_rng_seed = {seed}'])


def commands(seed: int, extra=()) -> dict:
  """{'demo': [argv], 'all_views': [train argv, eval argv]} of one seed (absolute paths), run from its folder."""
  bindings = seed_bindings(seed, extra)
  script = lambda name: [sys.executable, os.path.join(ROOT, name)]
  flags = ['--gin_configs', *demo.METHODS['NeRF'], '--gin_bindings', *ALL_VIEWS, *bindings]
  return {'demo': script('train.py') + (['--gin_bindings', *bindings] if bindings else []),
          'all_views': [script('train.py') + flags, script('eval.py') + flags]}


def shown(argv: list) -> str:
  """A command as a user types it in the repository: python, paths relative to it."""
  return cli.quoted(['python'] + [a[len(ROOT) + 1:] if a.startswith(ROOT + os.sep) else a for a in argv[1:]])


def run_timed(argv_list: list, cwd: str, log: str) -> float:
  """Runs each argv in cwd, output appended to log; their seconds."""
  start = time.perf_counter()
  with open(log, 'a') as out:
    for argv in argv_list:
      if subprocess.run(argv, cwd=cwd, stdout=out, stderr=subprocess.STDOUT, check=False).returncode:
        raise RuntimeError(f'{shown(argv)} failed in {cwd!r}; its output is in {log!r}')
  return round(time.perf_counter() - start, 1)


def means(run_dir: str, step: int) -> dict:
  """The metric means of a run's evaluation at step."""
  return results.read_record(os.path.join(evaluate.output_dir(run_dir, step), results.METRICS_FILENAME))['means']


def run_seed(seed: int, work: str, extra=()) -> dict:
  """Runs the demo and the all-views check for one seed in work/seed_<seed>/; the seed's record."""
  cwd = os.path.join(work, f'seed_{seed}')
  os.makedirs(cwd)
  cmds, log = commands(seed, extra), os.path.join(cwd, 'log.txt')
  load_before = os.getloadavg()[0]  # Other jobs on the machine: the wall times say little beside a high load.
  demo_seconds = run_timed([cmds['demo']], cwd, log)
  load = [round(load_before, 2), round(os.getloadavg()[0], 2)]
  all_views_seconds = run_timed(cmds['all_views'], cwd, log)
  cfgs = demo.method_configs(extra)
  step = cfgs['FreeNeRF'].max_steps
  runs = {name: os.path.join(cwd, cfg.checkpoint_dir) for name, cfg in cfgs.items()}
  return {'seed': seed, 'step': step,
          'demo': {'command': shown(cmds['demo']), 'seconds': demo_seconds, 'load_average': load,
                   'means': {name: means(run, step) for name, run in runs.items()},
                   'learning_curves': {name: learning_curve.read_rows(learning_curve.csv_path(run))
                                       for name, run in runs.items()}},
          'all_views': {'commands': [shown(argv) for argv in cmds['all_views']], 'seconds': all_views_seconds,
                        'means': means(os.path.join(cwd, 'out', 'all_views'), step)}}


def read_seeds(out: str) -> list:
  """Every seed record in out, by seed."""
  records = []
  for path in glob.glob(os.path.join(out, 'seed_*.json')):
    with open(path) as f:
      records.append(json.load(f))
  return sorted(records, key=lambda r: r['seed'])


def columns(record: dict) -> dict:
  """{column: value} of one seed's row: each method's metrics, FreeNeRF's PSNR lead, all views, seconds."""
  found = record['demo']['means']
  row = {f'{name} {metric}': found[name][metric]
         for metric in METRICS for name in demo.METHODS if found[name].get(metric) is not None}
  row['FreeNeRF lead psnr'] = found['FreeNeRF']['psnr'] - found['NeRF']['psnr']
  row['all views psnr'] = record['all_views']['means']['psnr']
  row['demo seconds'], row['all views seconds'] = record['demo']['seconds'], record['all_views']['seconds']
  return row


def spread(values: list) -> dict:
  """Mean, sample standard deviation (None for one value), n, minimum and maximum."""
  return dict(study_stats.spread(values), min=min(values), max=max(values))


def summary(records: list) -> dict:
  """{'rows': {seed: columns}, 'over_seeds': {column: spread}} of the seed records."""
  rows = {str(r['seed']): columns(r) for r in records}
  names = [name for name in rows[str(records[0]['seed'])] if all(name in row for row in rows.values())]
  return {'rows': rows, 'over_seeds': {name: spread([row[name] for row in rows.values()]) for name in names}}


def _cell(value, name: str) -> str:
  if value is None:
    return '-'
  return f'{value:.0f}' if 'seconds' in name else f'{value:.2f}' if 'psnr' in name else f'{value:.3f}'


def readme(records: list, table: dict, kind: str) -> str:
  """The README of a machine kind's folder of results/demo: per seed and over the seeds, and where each seed was
  measured."""
  names = list(table['over_seeds'])
  lines = [f'# The demo over seeds: {kind} machines', '', 'Written by `python -m tools.demo_seeds` (its docstring says '
           'what it runs); every number below is in `seed_<seed>.json` and `summary.json`. Per seed '
           '(`Config.jax_rng_seed`) the demo (`python train.py`, 2 views; its wall time from scratch) and the all-views '
           'check (the demo\'s NeRF on every training view, without LPIPS; tests/test_demo.py compares against it). '
           'PSNR, SSIM and LPIPS over the test views, depth MAE in world units, times in seconds. Measured where XLA '
           f'compiles for {kind} (`environment.cpu_isa`), whose float32 digits these are.', '',
           '| seed | ' + ' | '.join(names) + ' |', '|---' * (len(names) + 1) + '|']
  lines += [f'| {seed} | ' + ' | '.join(_cell(row.get(n), n) for n in names) + ' |'
            for seed, row in table['rows'].items()]
  for stat in ('mean', 'std', 'min', 'max'):
    lines.append(f'| {stat} | ' + ' | '.join(_cell(table['over_seeds'][n][stat], n) for n in names) + ' |')
  lines += ['', 'Measured on:', '']
  lines += [f'- seed {r["seed"]}: {where(r)}{_load(r)}; `{r["provenance"]["command"]}`' for r in records]
  return '\n'.join(lines) + '\n'


def _load(record: dict) -> str:
  """The 1-minute load average before and after the demo ran, in words ('' where not recorded)."""
  load = record['demo'].get('load_average')
  return f', load average {load[0]} before and {load[1]} after the demo' if load else ''


def where(record: dict) -> str:
  """Commit, date and machine of a record, in words."""
  prov, machine = record['provenance'], record['provenance']['machine']
  flags = next((w for w in prov['command'].split() if w.startswith('XLA_FLAGS=')), '')
  return (f'commit {prov["commit"]}, {prov["date"]}, {machine["cpu_count"]} CPUs ({machine["cpu"]}), '
          f'XLA for {machine.get("isa", "?")}{" (" + flags + ")" if flags else ""}, jax {machine["jax"]}')


def write_summary(folder: str) -> dict:
  """(Re)writes summary.json and README.md of a machine kind's folder from every seed record in it; the summary."""
  records = read_seeds(folder)
  table = summary(records)
  atomic.write_text(os.path.join(folder, SUMMARY), json.dumps(table, indent=1) + '\n')
  atomic.write_text(os.path.join(folder, README), readme(records, table, os.path.basename(folder)))
  return table


def index(out: str) -> str:
  """The README of results/demo: one line per machine kind with a folder of records."""
  lines = ['# The demo over seeds, per machine kind', '', 'Written by `python -m tools.demo_seeds`. A machine kind is '
           'the instruction set XLA compiles for: float32 results agree to the last digit only within a kind, so '
           'each kind has its records, and tests/test_demo.py pins the demo to those of the machine it runs on. '
           'Means over the seeds; wall seconds of `python train.py` from scratch.', '',
           '| kind | seeds | NeRF psnr | FreeNeRF psnr | smallest FreeNeRF lead psnr | demo seconds | folder |',
           '|---|---|---|---|---|---|---|']
  for kind in sorted(os.listdir(out)):
    if not os.path.isfile(os.path.join(out, kind, SUMMARY)):
      continue
    with open(os.path.join(out, kind, SUMMARY)) as f:
      over = json.load(f)['over_seeds']
    cells = [over['NeRF psnr']['mean'], over['FreeNeRF psnr']['mean'], over['FreeNeRF lead psnr']['min'],
             over['demo seconds']['mean']]
    names = ('psnr', 'psnr', 'psnr', 'seconds')
    lines.append(f'| {kind} | {over["NeRF psnr"]["n"]} | ' + ' | '.join(_cell(v, n) for v, n in zip(cells, names)) +
                 f' | [{kind}/]({kind}/README.md) |')
  return '\n'.join(lines) + '\n'


def checked_seeds(texts: list, extra=()) -> list:
  """The seeds of --seeds as integers, each once and a valid Config.jax_rng_seed with the extra bindings; a
  ValueError naming --seeds (or the binding) before any work."""
  demo.method_configs(extra)  # A bad --gin_bindings is named as itself, not as a seed's.
  seeds = []
  for text in texts:
    try:
      seed = int(text)
    except ValueError:
      raise ValueError(f'--seeds {text!r}: expected whole numbers (values of Config.jax_rng_seed)') from None
    if seed in seeds:
      raise ValueError(f'--seeds {" ".join(texts)}: seed {seed} is given twice; expected each seed once')
    try:
      demo.method_configs(seed_bindings(seed, extra))
    except ValueError as e:
      raise ValueError(f'--seeds {text}: {cli.one_line(e)}') from None
    seeds.append(seed)
  return seeds


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  argv = sys.argv[1:] if argv is None else argv
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--seeds', nargs='+', required=True, help='values of Config.jax_rng_seed')
  parser.add_argument('--out', default=os.path.join(ROOT, 'results', 'demo'),
                      help='the folder to commit (a folder per machine kind in it)')
  parser.add_argument('--work', default=os.path.join('out', 'demo_seeds'), help='where the runs are trained')
  parser.add_argument('--gin_bindings', nargs='+', default=[], help='extra bindings of every run')
  args = parser.parse_args(argv)
  args.seeds = checked_seeds(args.seeds, args.gin_bindings)
  folder = kind_dir(args.out)
  for seed in args.seeds:
    if os.path.exists(seed_file(folder, seed)):
      raise FileExistsError(f'{seed_file(folder, seed)!r} exists: seed {seed} is recorded for this machine kind; '
                            'remove the file to measure it again')
    if os.path.exists(os.path.join(args.work, f'seed_{seed}')):
      raise FileExistsError(f'{os.path.join(args.work, f"seed_{seed}")!r} exists: its runs would resume and their '
                            'times would not be whole runs; remove it or choose --work')
  os.makedirs(folder, exist_ok=True)
  command = ([f'XLA_FLAGS={os.environ["XLA_FLAGS"]}'] if os.environ.get('XLA_FLAGS') else []) + [
      'python', '-m', 'tools.demo_seeds', *argv]
  for seed in args.seeds:
    found = run_seed(seed, args.work, args.gin_bindings)
    atomic.write_text(seed_file(folder, seed), json.dumps(dict(found, provenance=provenance.record(command)),
                                                          indent=1) + '\n')
    table = write_summary(folder)
    atomic.write_text(os.path.join(args.out, README), index(args.out))
    print(f'seed {seed}: ' + ', '.join(f'{k} {_cell(v, k)}' for k, v in table['rows'][str(seed)].items()))
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
