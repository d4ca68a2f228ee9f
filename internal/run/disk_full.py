"""A training write that finds the disk full: one error (DiskFullError) naming what it wrote and the intact step,
orbax's reports of a failed save dropped.

Orbax writes each step into a temporary folder and renames it when complete, so a failed save leaves the checkpoints
before it as they were. Its threads, event loop and abandoned coroutines report the failure again and again, some as
late as exit; those reports (and only those) are dropped once a save has found the disk full.
"""

import contextlib
import errno
import inspect
import logging
import os
import re
import sys
import traceback
import warnings

import orbax.checkpoint as ocp

from internal.run import checkpoints


class DiskFullError(RuntimeError):
  """A write of training (a checkpoint save, or another file of its run) failed for lack of disk space; the
  checkpoints saved before it are intact."""


def _says_disk_full(text: str) -> bool:
  """True when an error message says a write found no space left (orbax and tensorstore wrap ENOSPC in text)."""
  return os.strerror(errno.ENOSPC) in text or f"os_error_code='{errno.ENOSPC}'" in text


def is_disk_full(err: BaseException) -> bool:
  """True for an error of a write that found no space left: OSError ENOSPC, or orbax's wrapping of it (a ValueError
  'RESOURCE_EXHAUSTED: ... No space left on device [os_error_code='28']')."""
  return (isinstance(err, OSError) and err.errno == errno.ENOSPC) or _says_disk_full(str(err))


ORBAX_DIR = os.path.dirname(os.path.dirname(os.path.abspath(ocp.__file__)))  # .../orbax


def _in_orbax(filename: str) -> bool:
  """True for a source file of orbax."""
  return os.path.abspath(filename).startswith(ORBAX_DIR + os.sep)


def _disk_full_record_filter(folder: str):
  """A logging filter: False for the records of a write that found the disk full (the DiskFullError says it) made by
  orbax: logged by orbax, of an error raised in orbax's code, or of an error naming a file in `folder` (the run's
  checkpoints: tensorstore's writes for orbax fail in C++, their errors carry no Python frames); True otherwise."""
  names = tuple({os.path.abspath(folder) + os.sep, os.path.realpath(folder) + os.sep})

  def keep(record: logging.LogRecord) -> bool:
    err = record.exc_info[1] if record.exc_info else None
    frames = [frame.f_code.co_filename for frame, _ in traceback.walk_tb(err.__traceback__)] if err else []
    texts = [record.getMessage()] + ([str(err)] if err is not None else [])
    from_orbax = (_in_orbax(record.pathname) or any(map(_in_orbax, frames))
                  or any(name in text for name in names for text in texts))
    return not (from_orbax and (_says_disk_full(record.getMessage()) or (err is not None and is_disk_full(err))))
  return keep


def _orbax_unawaited_warnings() -> str:
  """The message pattern of the warning that a coroutine of orbax (a function, method or inner function of its
  loaded modules, by qualified name) was never awaited; other coroutines' warnings do not match."""
  names = {name for module_name, module in list(sys.modules.items()) if module_name.split('.')[0] == 'orbax'
           for name, value in list(vars(module).items()) if getattr(value, '__module__', None) == module_name
           and (inspect.isfunction(value) or inspect.isclass(value))}
  return rf"coroutine '(?:{'|'.join(map(re.escape, sorted(names)))})(?:\.[^']*)?' was never awaited"


def _is_closed_loop_error(unraisable) -> bool:
  """True for the error of a callback into the event loop of an orbax save that already failed and closed it."""
  return isinstance(unraisable.exc_value, RuntimeError) and str(unraisable.exc_value) == 'Event loop is closed'


def _drop_failed_save_reports(folder: str):
  """Drops orbax's own reports of a write into `folder` that found the disk full; returns the function that stops
  dropping them.

  They are the absl records of its save threads, asyncio's 'Future exception was never retrieved' (logged when
  the failed write is garbage collected, possibly at exit) and, from writes still running when the save failed,
  'Event loop is closed' errors that Python reports as unraisable.
  """
  loggers = [logging.getLogger(name) for name in ('absl', 'asyncio')]
  keep = _disk_full_record_filter(folder)
  for logger in loggers:
    logger.addFilter(keep)
  previous = sys.unraisablehook

  def hook(unraisable):
    if not _is_closed_loop_error(unraisable):
      previous(unraisable)

  sys.unraisablehook = hook

  def restore():
    for logger in loggers:
      logger.removeFilter(keep)
    if sys.unraisablehook is hook:
      sys.unraisablehook = previous
  return restore


def _what_found_it_full(err: BaseException, folder: str) -> str:
  """'writing <file>' for a write of a named file outside the checkpoint folder (tensorboard's events, the learning
  curve and its clock, the settings), else 'saving a checkpoint in <folder>' (orbax's errors name no file)."""
  written = getattr(err, 'filename', None)
  inside = written is not None and os.path.abspath(written).startswith(os.path.abspath(folder) + os.sep)
  return f'writing {written!r}' if written is not None and not inside else f'saving a checkpoint in {folder!r}'


@contextlib.contextmanager
def stop_when_disk_full(run_dir: str):
  """Turns a write in the block that ran out of disk space (a checkpoint save, tensorboard's events, the learning
  curve) into DiskFullError naming what it wrote and the intact step.

  Orbax writes each step into a temporary folder and renames it when complete, so a failed save leaves the
  checkpoints before it as they were (the temporary folder is removed when training next starts). Orbax's own
  reports of the failed save (its records of writes that found the disk full, the warnings that its coroutines
  were never awaited) are dropped for the one line, also after the block: some come when its abandoned writes end
  or are collected, as late as exit. What does not come from orbax is kept, and without a full disk nothing stays.
  """
  folder = os.path.join(run_dir, checkpoints.CHECKPOINT_SUBDIR)
  restore = _drop_failed_save_reports(folder)
  full = False
  try:
    yield
  except Exception as err:  # pylint: disable=broad-except  (orbax re-raises the writer's error as it was)
    full = is_disk_full(err)
    if not full:
      raise
    warnings.filterwarnings('ignore', message=_orbax_unawaited_warnings(), category=RuntimeWarning)
    try:
      kept = f'the newest intact checkpoint, step {checkpoints.latest_step(run_dir)}, is kept'
    except checkpoints.NoCheckpointError:
      kept = 'no earlier checkpoint exists'
    raise DiskFullError(f'no space left on the device while {_what_found_it_full(err, folder)}; {kept}. Free disk '
                        'space (or lower Config.checkpoint_keep) and run the same command again to resume') from err
  finally:
    if not full:
      restore()
