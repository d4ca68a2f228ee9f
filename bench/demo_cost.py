"""The demo's cost at its length against its former length, side by side in one run: results/demo_cost/<kind>.json.

  python -m bench.demo_cost [--repeats 1] [--out results/demo_cost] [--work out/demo_cost]

Each repeat runs the whole demo (`python train.py`, the scene generated, both methods trained, evaluated and
rendered) from scratch twice, each in its own folder under --work: as configured, and at its former length (FORMER:
700 steps and 32 coarse samples a ray, where configs/demo_forward.gin now has 500 and 16). Each run's wall seconds,
CPU seconds (user + system of the process and its children) and both methods' test PSNR are recorded. CPU seconds
count only the time a core ran the demo, so other jobs move them less than wall seconds; their ratio estimates the new demo's time on another
machine from the former one's measured there (the two lengths run the same operations, in other numbers). Writes
<out>/<kind>.json (the machine kind: environment.cpu_isa; every run, the medians, the ratios, provenance with the
load average) and <out>/README.md over every kind's file.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import glob
import json
import os
import resource
import statistics
import subprocess
import sys
import time

from internal import atomic
from internal import cli
from internal import demo
from internal import environment
from internal import runs
from tools import provenance

FORMER = ['Config.max_steps = 700', 'Config.checkpoint_every = 350', 'NerfModel.num_coarse_samples = 32']
LENGTHS = {'now': [], 'former': FORMER}


def children_cpu_seconds() -> float:
  """User + system seconds of every finished child process of this one."""
  usage = resource.getrusage(resource.RUSAGE_CHILDREN)
  return usage.ru_utime + usage.ru_stime


def run_demo(bindings: list, cwd: str) -> dict:
  """Runs `python train.py [--gin_bindings ...]` in a new folder cwd; its wall and CPU seconds and the load."""
  os.makedirs(cwd)
  argv = [sys.executable, os.path.join(provenance.ROOT, 'train.py')] + (['--gin_bindings', *bindings] if bindings else [])
  load, cpu, wall = os.getloadavg()[0], children_cpu_seconds(), time.perf_counter()
  with open(os.path.join(cwd, 'log.txt'), 'w') as log:
    if subprocess.run(argv, cwd=cwd, stdout=log, stderr=subprocess.STDOUT, check=False).returncode:
      raise RuntimeError(f'the demo failed in {cwd!r}; its output is in {os.path.join(cwd, "log.txt")!r}')
  return {'wall_seconds': round(time.perf_counter() - wall, 1), 'cpu_seconds': round(children_cpu_seconds() - cpu, 1),
          'load_average': [round(load, 2), round(os.getloadavg()[0], 2)], 'psnr': mean_test_psnrs(bindings, cwd)}


def mean_test_psnrs(bindings: list, cwd: str) -> dict:
  """{method: mean test PSNR} of the demo that ran in cwd with bindings (its digits: this machine kind's)."""
  return {name: runs.metrics_record(os.path.join(cwd, config.checkpoint_dir), config.max_steps)['means']['psnr']
          for name, config in demo.method_configs(bindings).items()}


def measure(repeats: int, work: str) -> dict:
  """{'runs': {length: [run, ...]}, 'median': {length: {wall_seconds, cpu_seconds}}, 'ratio': now / former}."""
  found = {length: [] for length in LENGTHS}
  for repeat in range(repeats):
    for length, bindings in LENGTHS.items():  # Alternating, so that a change of load touches both alike.
      found[length].append(run_demo(bindings, os.path.join(work, f'{length}_{repeat}')))
  median = {length: {key: statistics.median(r[key] for r in rows) for key in ('wall_seconds', 'cpu_seconds')}
            for length, rows in found.items()}
  ratio = {key: round(median['now'][key] / median['former'][key], 3) for key in ('wall_seconds', 'cpu_seconds')}
  return {'former_bindings': FORMER, 'runs': found, 'median': median, 'ratio_now_to_former': ratio}


def readme(out: str) -> str:
  """The README over every kind's record in out."""
  lines = ['# The demo\'s cost, now and at its former length', '',
           'Written by `python -m bench.demo_cost` (its docstring says what it runs): per machine kind '
           '(`environment.cpu_isa`), the medians of the whole demo run from scratch as configured and at '
           'its former length (700 steps and 32 coarse samples a ray), alternating in one run. Every number is in '
           'the kind\'s JSON file.', '',
           '| kind | repeats | wall seconds now | wall seconds former | CPU seconds now | CPU seconds former | '
           'CPU ratio now / former | file |', '|---|---|---|---|---|---|---|---|']
  for path in sorted(glob.glob(os.path.join(out, '*.json'))):
    with open(path) as f:
      record = json.load(f)
    now, former = record['median']['now'], record['median']['former']
    lines.append(f'| {os.path.basename(path)[:-5]} | {len(record["runs"]["now"])} | {now["wall_seconds"]:.1f} | '
                 f'{former["wall_seconds"]:.1f} | {now["cpu_seconds"]:.1f} | {former["cpu_seconds"]:.1f} | '
                 f'{record["ratio_now_to_former"]["cpu_seconds"]:.3f} | [{os.path.basename(path)}]({os.path.basename(path)}) |')
  return '\n'.join(lines) + '\n'


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--repeats', type=int, default=1, help='pairs of demos, alternating')
  parser.add_argument('--out', default=os.path.join(provenance.ROOT, 'results', 'demo_cost'))
  parser.add_argument('--work', default=os.path.join('out', 'demo_cost'), help='where the demos run (a new folder)')
  args = parser.parse_args(argv)
  if args.repeats < 1:
    raise ValueError(f'--repeats {args.repeats}: expected a whole number >= 1')
  path = os.path.join(args.out, f'{environment.cpu_isa()}.json')
  for taken, what in ((path, 'this machine kind is recorded'), (args.work, 'its runs would resume, not start over')):
    if os.path.exists(taken):
      raise FileExistsError(f'{taken!r} exists: {what}; move it away first')
  record = {**measure(args.repeats, args.work), 'provenance': provenance.record(sys.argv)}
  os.makedirs(args.out, exist_ok=True)
  atomic.write_text(path, json.dumps(record, indent=1) + '\n')
  atomic.write_text(os.path.join(args.out, 'README.md'), readme(args.out))
  print(readme(args.out))
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
