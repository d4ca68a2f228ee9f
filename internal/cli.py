"""What the scripts share at the command line: user errors as one line and exit status 2, robust printing.

A user error (a bad setting, a missing or malformed data file, a run directory that must not be touched, an
output that exists) prints `error: <message>` on stderr and exits with USAGE_ERROR_STATUS, the status argparse
uses for bad flags. A run stopped for non-finite values (Config.max_skipped_steps consecutive skipped updates,
or one under Config.nonfinite_grad_policy = 'raise') prints one line too and exits with NONFINITE_STATUS.
Anything else is a bug and keeps its traceback (exit status 1). FREENERF_DEBUG=1 in the
environment shows the traceback of user errors too.
"""

import os
import sys

from internal import checkpoints
from internal import distributed
from internal import run_dir
from internal import train_step

USAGE_ERROR_STATUS = 2
NONFINITE_STATUS = 3
DEBUG_ENV = 'FREENERF_DEBUG'
# ValueError covers Config validation, gin's unknown bindings and the loaders' DatasetError; FileNotFoundError
# covers missing data and NoCheckpointError; FileExistsError is an evaluation or rendering that exists already;
# PrimaryFailed is what the other processes of a several-process training say when process 0 met such an error.
USER_ERRORS = (ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, run_dir.RunDirError,
               checkpoints.NoCheckpointError, distributed.PrimaryFailed)


def robust_streams() -> None:
  """Makes stdout/stderr print any text (e.g. a path of non-UTF-8 bytes) with backslash escapes, never fail."""
  for stream in (sys.stdout, sys.stderr):
    if hasattr(stream, 'reconfigure'):
      stream.reconfigure(errors='backslashreplace')


def one_line(err: BaseException) -> str:
  """The error's message on one line (gin's multi-line messages joined)."""
  return ' '.join(line.strip() for line in str(err).splitlines() if line.strip()) or type(err).__name__


def run(main) -> int:
  """Calls main() -> exit status; a user error prints one line on stderr (status 2, or 3 for non-finite values)."""
  robust_streams()
  try:
    return main()
  except (*USER_ERRORS, train_step.NonFiniteError) as err:
    if os.environ.get(DEBUG_ENV, '') not in ('', '0'):
      raise
    print(f'error: {one_line(err)}', file=sys.stderr)
    return NONFINITE_STATUS if isinstance(err, train_step.NonFiniteError) else USAGE_ERROR_STATUS


class LineFile:
  """A text stream for tqdm when stderr is not a terminal: each refresh becomes one line, no carriage returns."""

  def __init__(self, stream):
    self.stream = stream

  def write(self, text: str) -> None:
    text = text.replace('\r', '').strip()
    if text:
      self.stream.write(text + '\n')

  def flush(self) -> None:
    self.stream.flush()


def progress_kwargs(stream=None) -> dict:
  """tqdm arguments: a live bar on a terminal; a line at most every 5 s in a log file or pipe."""
  stream = sys.stderr if stream is None else stream
  if stream.isatty():
    return {'file': stream, 'dynamic_ncols': True}
  return {'file': LineFile(stream), 'mininterval': 5., 'ncols': 100}
