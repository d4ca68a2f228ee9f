"""Printing that never fails and progress bars that suit a terminal or a log file."""

import sys


def robust_streams() -> None:
  """Makes stdout/stderr print any text (e.g. a path of non-UTF-8 bytes) with backslash escapes, never fail."""
  for stream in (sys.stdout, sys.stderr):
    if hasattr(stream, 'reconfigure'):
      stream.reconfigure(errors='backslashreplace')


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


def duration(seconds: float) -> str:
  """seconds in the largest unit that is at least one of them: '45 s', '12 min', '3.5 h', '2.1 days', '31.7 years'."""
  units = (('years', 365.25 * 86400), ('days', 86400), ('h', 3600), ('min', 60))
  unit, size = next(((unit, size) for unit, size in units if seconds >= size), ('s', 1))
  text = f'{seconds / size:.3g} {unit}'
  return text[:-1] if text.startswith('1 ') and unit in ('years', 'days') else text  # '1 day'.


def progress_kwargs(stream=None) -> dict:
  """tqdm arguments: a live bar on a terminal; a line at most every 5 s in a log file or pipe."""
  stream = sys.stderr if stream is None else stream
  if stream.isatty():
    return {'file': stream, 'dynamic_ncols': True}
  return {'file': LineFile(stream), 'mininterval': 5., 'ncols': 100}
