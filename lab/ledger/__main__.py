"""`python -m lab.ledger`: the ledger of paper-length runs (lab/ledger/ledger.toml), what a GPU window trains next
and hands back (window.py), and what came back, committed (commit.py).

Usage, inside a GPU window (`bash lab/lease.sh` runs these; docs/benchmarks.md, "GPU windows: the ledger"):
  python -m lab.ledger plan --work DIR [--budget S] [--allow_cpu]   the window's plan, printed; DIR/plan.env,
      DIR/window.json (refused when jax sees no GPU, unless --allow_cpu: the tests' tiny ledger)
  python -m lab.ledger next --work DIR                the next run's folder DIR/runs/RUN made ready from its
      committed checkpoint, its train.py arguments in DIR/RUN.args, RUN and ACTION (train | evaluate) in
      DIR/next.env; status 1 when the window has nothing left to do (every run evaluated, or one was cut)
  python -m lab.ledger retry-base --work DIR          after a failed training: a run this window started at
      step 0 with another variant and that saved no checkpoint goes again with base (status 1 for any other run:
      no retry drops steps a window trained)
  python -m lab.ledger pack RUN --work DIR --out OUT  the run's folder as OUT/run_RUN.tar.gz (newest intact
      checkpoint with its SHA-256 sums, curve, clock, settings, tensorboard: what the next window resumes from)
      and, once evaluated, OUT/eval_RUN.tar.gz (metrics and test-view renders)
  python -m lab.ledger pack-window --work DIR --out OUT   the window's plan, logs and timings as OUT/window.tar.gz
Afterwards, on the CPU machine (lab/ledger/commit.py):
  python -m lab.ledger unpack FOLDER                  what came back, into results/gpu/ledger/ (then git commit)
  python -m lab.ledger model RUN --into DIR           a finished run's model.npz as a run folder for eval / render
Every command takes --ledger (default lab/ledger/ledger.toml), --results (results/gpu/ledger) and --data (.devdata,
where `python -m lab.prepare_lease` put the packs).
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import os
import sys

from internal import cli
from lab.ledger import commit
from lab.ledger import window

COMMANDS = {  # The flags each command needs.
    'plan': ['work'], 'next': ['work'], 'retry-base': ['work'], 'pack': ['target', 'work', 'out'],
    'pack-window': ['work', 'out'], 'unpack': ['target'], 'model': ['target', 'into']}


def _parser() -> argparse.ArgumentParser:
  parser = argparse.ArgumentParser(prog='python -m lab.ledger', description=__doc__.splitlines()[0])
  parser.add_argument('command', choices=list(COMMANDS))
  parser.add_argument('target', nargs='?', default='', help='pack, model: the run; unpack: the folder that came back')
  parser.add_argument('--ledger', default=window.LEDGER)
  parser.add_argument('--results', default=window.RESULTS)
  parser.add_argument('--data', default=window.DATA)
  parser.add_argument('--work', default='', help='the window\'s working folder (run folders, logs)')
  parser.add_argument('--out', default='', help='pack, pack-window: the folder that comes back ($OUT)')
  parser.add_argument('--budget', type=int, default=0, help='plan: the window\'s budget in seconds')
  parser.add_argument('--allow_cpu', action='store_true', help='plan: a window on the CPU (the tests\' tiny ledger)')
  parser.add_argument('--into', default='', help='model: the run folder to write')
  return parser


def _check(args, ledger: window.Ledger) -> None:
  """ValueError naming the first flag the command lacks or a run the ledger does not hold; FileNotFoundError for an
  --out that is no folder."""
  missing = [name for name in COMMANDS[args.command] if not getattr(args, name)]
  if missing:
    raise ValueError(f'{args.command} needs ' + ', '.join(('RUN/FOLDER' if n == 'target' else f'--{n}')
                                                         for n in missing))
  if args.command in ('pack', 'model') and args.target not in [r.name for r in ledger.runs]:
    raise ValueError(f'{args.target!r} is no run of {args.ledger}; expected one of {[r.name for r in ledger.runs]}')
  if args.command in ('pack', 'pack-window') and not os.path.isdir(args.out):
    raise FileNotFoundError(f'--out {args.out!r} is no folder; expected the folder that comes back ($OUT)')


def main(argv=None) -> int:
  """CLI entry point; returns the exit status (1: `next` or `retry-base` found nothing to do)."""
  args = _parser().parse_args(argv)
  ledger = window.load(args.ledger)
  _check(args, ledger)
  if args.command == 'next':
    return 0 if window.ready_run(ledger, args.results, args.work, args.data) else 1
  if args.command == 'retry-base':
    return 0 if window.retry_base(ledger, args.work, args.data) else 1
  {'plan': lambda: window.plan(ledger, args.results, args.work, args.budget, args.allow_cpu),
   'pack': lambda: window.pack(ledger, args.target, args.work, args.out),
   'pack-window': lambda: window.pack_window(args.work, args.out),
   'unpack': lambda: commit.unpack(ledger, args.target, args.results),
   'model': lambda: commit.model_run_dir(ledger, args.target, args.results, args.data, args.into)}[args.command]()
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
