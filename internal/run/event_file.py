"""Tensorboard's event file of a run, written in the caller's thread: a write that fails raises where it was made.

tensorboardX.SummaryWriter writes from a thread of its own: on a full disk that thread died with a traceback, its
queue filled, and the training loop's next add_scalar waited for it forever. Here every write happens in the
thread that logs, and a failed one is an OSError naming the file (disk_full turns ENOSPC into one line).
"""

import contextlib
import os
import socket
import time

from tensorboardX import record_writer
from tensorboardX import summary
from tensorboardX.proto import event_pb2

FLUSH_SECONDS = 10.  # How stale tensorboard's view of a running training may be (each flush fsyncs the file).


@contextlib.contextmanager
def _naming(path: str):
  """Re-raises an OSError without a file name (a failed write or flush) as one naming path."""
  try:
    yield
  except OSError as err:
    if err.filename is not None:
      raise
    raise OSError(err.errno, err.strerror, path) from err


class EventWriter:
  """add_scalar and add_image as tensorboardX.SummaryWriter's, into a new event file in folder; a context manager
  that closes it."""

  def __init__(self, folder: str):
    os.makedirs(folder, exist_ok=True)
    # The process id keeps two trainings started within a second (a resume) from sharing a file.
    self.path = os.path.join(folder, f'events.out.tfevents.{time.time():.0f}.{socket.gethostname()}.{os.getpid()}')
    with _naming(self.path):
      self._records = record_writer.RecordWriter(self.path)
    self._next_flush = 0.  # The header is flushed at once: a disk full already is found before training.
    self._write(event_pb2.Event(wall_time=time.time(), file_version='brain.Event:2'))

  def add_scalar(self, tag: str, value, step: int) -> None:
    """Logs a scalar at step."""
    self._write(event_pb2.Event(summary=summary.scalar(tag, value), wall_time=time.time(), step=int(step)))

  def add_image(self, tag: str, image, step: int, dataformats: str = 'CHW') -> None:
    """Logs an image (uint8, or floats in [0, 1]) at step."""
    self._write(event_pb2.Event(summary=summary.image(tag, image, dataformats=dataformats), wall_time=time.time(),
                                step=int(step)))

  def _write(self, event) -> None:
    """Appends event; flushes when FLUSH_SECONDS passed since the last flush."""
    with _naming(self.path):
      self._records.write(event.SerializeToString())
    if time.monotonic() >= self._next_flush:
      self.flush()

  def flush(self) -> None:
    """Writes what is buffered to the disk."""
    with _naming(self.path):
      self._records.flush()
    self._next_flush = time.monotonic() + FLUSH_SECONDS

  def close(self) -> None:
    """Flushes and closes the file."""
    with _naming(self.path):
      self._records.close()

  def __enter__(self):
    return self

  def __exit__(self, *exc):
    self.close()
    return False
