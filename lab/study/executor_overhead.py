"""What running a cell through an executor costs beyond the cell's own process (docs/benchmarks.md).

  python -m lab.study.executor_overhead [--cells 8] [--address ADDRESS] [--out results/cluster/overhead.json]

Makes a study of --cells finished cells (each with a cell.json, so that its cell process starts, imports, claims
the cell, finds it done and exits: the cell's own start-up) and runs each one after another through the local
executor and through Ray (a local cluster, or --address), interleaved. Per cell, the overhead is the time from
submitting it to its result in the runner minus the seconds its cell process ran. Writes the medians, the
maxima and the first Ray cell (a worker starting) with the machine and versions to --out.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import json
import os
import statistics
import sys
import tempfile
import time

from internal import atomic
from internal import cli
from tools import provenance
from lab.study import dispatch
from lab.study import spec as study_spec

STUDY = 'name = "overhead"\n[methods.m]\n[scenes.s]\n[[axis]]\nname = "i"\nbinding = "Config.jax_rng_seed"\n'


def finished_cells(root: str, count: int) -> list:
  """Folders of count finished cells of a one-axis study under root."""
  study = study_spec.parse(STUDY + f'values = {list(range(count))}\n', 'overhead.toml')
  paths = []
  for cell in study_spec.cells(study):
    path = os.path.join(root, study.name, cell.cell_id)
    os.makedirs(path)
    atomic.write_text(os.path.join(path, 'cell.json'), json.dumps({'cell': cell.cell_id, 'step': 0}))
    paths.append(path)
  return paths


def timed(executor, path: str) -> dict:
  """{'outer': seconds from submit to result, 'inner': seconds the cell process ran} of one cell."""
  tic = time.perf_counter()
  status, inner = executor.submit(path).result()
  if status:
    raise RuntimeError(f'the cell process of {path} ended with status {status}')
  return {'outer': time.perf_counter() - tic, 'inner': inner}


def summary(times: list) -> dict:
  overhead = [t['outer'] - t['inner'] for t in times]
  return {'cells': len(times), 'overhead_median_s': statistics.median(overhead), 'overhead_max_s': max(overhead),
          'cell_startup_median_s': statistics.median(t['inner'] for t in times)}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(prog='python -m lab.study.executor_overhead', description=__doc__.split('\n')[0])
  parser.add_argument('--cells', type=int, default=8, help='cells per executor')
  parser.add_argument('--address', help='a Ray cluster (default: a local one started here)')
  parser.add_argument('--out', default='results/cluster/overhead.json', help='the JSON to write')
  args = parser.parse_args(argv)
  if args.cells < 2:
    raise ValueError(f'--cells {args.cells}; expected >= 2 (the first Ray cell starts a worker)')
  from lab.study import ray_executor as study_ray  # pylint: disable=import-outside-toplevel  (Ray is an optional extra)
  job = dispatch.new_job()
  local = dispatch.LocalExecutor([{}], job)
  ray_executor = study_ray.RayExecutor(args.address, study_spec.Resources(), job)
  with tempfile.TemporaryDirectory() as root:
    times = {'local': [], 'ray': []}
    for path in finished_cells(root, args.cells):
      times['local'].append(timed(local, path))
      times['ray'].append(timed(ray_executor, path))
  local.close()
  ray_executor.close()
  record = {'command': cli.command_line('lab.study.executor_overhead', argv),
            'commit': provenance.git_commit(dispatch.REPO), 'date': time.strftime('%Y-%m-%d %H:%M %z'),
            'machine': dict(provenance.machine(), ray=ray_executor.ray.__version__),
            'cluster': args.address or 'local (started by the command)',
            'local': summary(times['local']), 'ray': summary(times['ray'][1:]),
            'ray_first_cell_overhead_s': times['ray'][0]['outer'] - times['ray'][0]['inner'], 'per_cell': times}
  os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
  atomic.write_text(args.out, json.dumps(record, indent=1))
  print(json.dumps({k: record[k] for k in ('local', 'ray', 'ray_first_cell_overhead_s')}, indent=1))
  print(args.out)
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
