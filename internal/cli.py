"""What the scripts share at the command line: user errors as one line and exit status 2, robust printing.

A user error (a bad setting, a missing or malformed data file, a run directory that must not be touched, an
output that exists) prints `error: <message>` on stderr and exits with USAGE_ERROR_STATUS, the status argparse
uses for bad flags. A run stopped for non-finite values (Config.max_skipped_steps consecutive skipped updates,
or one under Config.nonfinite_grad_policy = 'raise') prints one line too and exits with NONFINITE_STATUS.
A checkpoint save that finds the disk full (the earlier checkpoints stay intact), or any other write that does,
prints one line and exits with DISK_FULL_STATUS. Running out of accelerator memory is a user error too: its line
names Config.batch_size (training, with XLA's estimate of the compiled step) or Config.render_chunk_size
(rendering); so is running out of host memory drawing the training batch (Config.batch_size). Ctrl-C outside the
training loop (which saves a checkpoint and stops itself) prints `interrupted: ...` and exits with 128 + SIGINT,
whatever exception the interrupted code raised (before main, while a script imports, internal/interrupt.py prints
the same line).
Anything else is a bug and keeps its traceback (exit status 1). FREENERF_DEBUG=1 in the
environment shows the traceback of user errors too. Warnings print as one line `warning: <message>`.
"""

import argparse
import os
import re
import shlex
import signal
import sys
import threading
import warnings

from internal import config_loader
from internal import environment
from internal import interrupt
from internal import progress
from internal.run import checkpoints
from internal.run import disk_full
from internal.run import distributed
from internal.run import out_of_memory
from internal.run import run_dir
from internal.training import train_step

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG_DIR = os.path.join(REPOSITORY, 'configs')
# The demo's FreeNeRF: the short CPU schedule (demo.gin), then its scene, 2 views and NeRF model (demo_forward.gin).
DEMO_CONFIGS = [os.path.join(CONFIG_DIR, name) for name in ('demo.gin', 'demo_forward.gin')]
USAGE_ERROR_STATUS = 2
NONFINITE_STATUS = 3
DISK_FULL_STATUS = 4  # disk_full.DiskFullError or another write without space: free space and rerun the command.
DEBUG_ENV = 'FREENERF_DEBUG'
# ValueError covers Config validation, gin's unknown bindings and the loaders' DatasetError; FileNotFoundError
# covers missing data and NoCheckpointError; FileExistsError is an evaluation or rendering that exists already;
# PrimaryFailed is what the other processes of a several-process training say when process 0 met such an error;
# OutOfMemoryError is XLA's RESOURCE_EXHAUSTED or the host batch's MemoryError, named by the setting to lower.
USER_ERRORS = (ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, run_dir.RunDirError,
               checkpoints.NoCheckpointError, distributed.PrimaryFailed, out_of_memory.OutOfMemoryError)


def one_line(err: BaseException) -> str:
  """The error's message on one line (gin's multi-line messages joined)."""
  return ' '.join(line.strip() for line in str(err).splitlines() if line.strip()) or type(err).__name__


# Errors that stop a run for a reason of their own, with their exit status (a user error's is USAGE_ERROR_STATUS).
OWN_STATUS = ((train_step.NonFiniteError, NONFINITE_STATUS), (disk_full.DiskFullError, DISK_FULL_STATUS))


def signal_status(signum) -> int:
  """The exit status of a command stopped by signal signum (128 + signum, as shells report it)."""
  return 128 + int(signum)


def format_warning(message, category, filename, lineno, line=None) -> str:
  """A warning as the scripts print it: one line `warning: ...`, without Python's file, line and source."""
  del category, filename, lineno, line
  return f'warning: {one_line(message)}\n' if str(message).strip() else 'warning\n'


def run(main) -> int:
  """Calls main() -> exit status; a user error prints one line on stderr (status 2, or 3 / 4 of OWN_STATUS).

  Ctrl-C outside training's own handling (eval.py, render.py, training before its loop) prints one line too and
  exits with signal_status(SIGINT), as training stopped by SIGINT does; so does any exception once a SIGINT arrived
  (what an interrupted import made of it), and a SIGINT during the script's imports that they swallowed stops it
  before main. Warnings print as one line `warning: ...` while main runs.
  """
  progress.robust_streams()
  debug = os.environ.get(DEBUG_ENV, '') not in ('', '0')
  python_format, warnings.formatwarning = warnings.formatwarning, format_warning
  with interrupt.recording() as sigint:
    try:
      sigint.raise_if_received()
      return main()
    except BaseException as err:  # pylint: disable=broad-except  (what is not named below is raised again)
      status = None if debug else _one_line_status(err, sigint.received)
      if status is None:
        raise
      return status
    finally:
      warnings.formatwarning = python_format


def _one_line_status(err: BaseException, interrupted: bool):
  """Prints err's one line and returns the exit status; None for a bug (or SystemExit), whose traceback stays."""
  if isinstance(err, KeyboardInterrupt) or (interrupted and isinstance(err, Exception)):
    if threading.current_thread() is threading.main_thread():  # A Ctrl-C during the exit's cleanup (Ray's) would
      signal.signal(signal.SIGINT, signal.SIG_IGN)              # escape here and kill the process by signal.
    print(interrupt.MESSAGE, file=sys.stderr)
    return signal_status(signal.SIGINT)
  if isinstance(err, (*USER_ERRORS, *(cls for cls, _ in OWN_STATUS))):
    print(f'error: {one_line(err)}', file=sys.stderr)
    return next((status for cls, status in OWN_STATUS if isinstance(err, cls)), USAGE_ERROR_STATUS)
  if isinstance(err, OSError) and disk_full.is_disk_full(err):
    where = f' writing {err.filename!r}' if err.filename else ''
    print(f'error: no space left on the device{where}; free disk space and run the same command again',
          file=sys.stderr)
    return DISK_FULL_STATUS
  return None


MULTI_VALUE_FLAGS = ('--gin_configs', '--gin_bindings')


def quoted(words) -> str:
  """Words as one shell line a user can paste: plain words bare, others in double quotes (a gin binding's 'strings'
  stay readable), or shell-quoted where double quotes would expand them."""
  return ' '.join(w if re.fullmatch(r'[\w@%+=:,./-]+', w) else f'"{w}"' if not re.search(r'["$`\\!]', w)
                  else shlex.quote(w) for w in words)


# An absolute path in a word or a text: a '/' that starts it or follows '=', a quote, a space or a bracket.
ABSOLUTE_PATH = re.compile(r"(?<![\w.~/-])/[\w.@+,=-]+(?:/[\w.@+,=-]*)*")


def relative_paths(text: str) -> str:
  """text with each absolute path written relative to the repository (/work/x/out -> ../x/out from /work/repo),
  so that what a command writes into a committed record names no machine's folders."""
  return ABSOLUTE_PATH.sub(lambda m: os.path.relpath(m.group(0), REPOSITORY), text)


def recorded_command(words) -> str:
  """A command's words as the line a record keeps: quoted, each absolute path relative to the repository."""
  return quoted([relative_paths(w) for w in words])


def command_line(module: str, argv=None) -> str:
  """The line that ran `python -m module` with argv (default: this process's arguments), as a record keeps it."""
  return recorded_command(['python', '-m', module] + list(sys.argv[1:] if argv is None else argv))


def split_flag_values(argv, flags=MULTI_VALUE_FLAGS):
  """argv with '--gin_bindings=A' split into '--gin_bindings', 'A' for each of the flags, so that values after it
  join it."""
  out = []
  for arg in argv:
    name, sep, value = arg.partition('=')
    out.extend([name, value] if sep and name in flags else [arg])
  return out


class FlagParser(argparse.ArgumentParser):
  """An ArgumentParser that accepts `--flag=A B` for its multi-value flags, multi_value_flags (default the gin
  flags; argparse alone takes only A)."""

  def __init__(self, *args, multi_value_flags=MULTI_VALUE_FLAGS, **kwargs):
    super().__init__(*args, **kwargs)
    self.multi_value_flags = tuple(multi_value_flags)

  def parse_known_args(self, args=None, namespace=None):
    args = sys.argv[1:] if args is None else args
    return super().parse_known_args(split_flag_values(args, self.multi_value_flags), namespace)


class PrintEnvironment(argparse.Action):
  """--env: prints environment.describe() and exits with status 0, like --help."""

  def __init__(self, option_strings, dest, **kwargs):
    super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

  def __call__(self, parser, namespace, values, option_string=None):
    print(environment.describe())
    parser.exit()


def flag_parser(description: str, more_multi_value_flags=()) -> argparse.ArgumentParser:
  """An argument parser with --gin_configs / --gin_bindings, each repeatable and taking one or more values, and
  --env; the caller's own such flags (more_multi_value_flags, added by it) take `--flag=A B` as they do."""
  parser = FlagParser(description=description, multi_value_flags=MULTI_VALUE_FLAGS + tuple(more_multi_value_flags))
  parser.add_argument('--env', action=PrintEnvironment,
                      help='print the environment for a bug report (jax backend and devices, package versions, '
                           'numerics) and exit')
  parser.add_argument('--gin_configs', action='extend', nargs='+', default=[], metavar='FILE',
                      help='gin config files, applied in order')
  parser.add_argument('--gin_bindings', action='extend', nargs='+', default=[], metavar='BINDING',
                      help='gin bindings applied after the files, e.g. "Config.freq_reg_end = 20000"')
  return parser


def config_from_flags(args: argparse.Namespace):
  """The validated Config of parsed flags; the demo's FreeNeRF configs when no --gin_configs was given."""
  return config_loader.load_config(args.gin_configs or DEMO_CONFIGS, args.gin_bindings)
