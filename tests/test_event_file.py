"""The run's tensorboard event file: readable records, and a write on a full disk raises at once, naming the file."""

import errno
import io
import os
import struct
import threading

import numpy as np
import pytest
from tensorboardX import record_writer
from tensorboardX.proto import event_pb2

from internal.run import event_file


def _events(folder) -> list:
  """The events of the one event file in folder."""
  (name,) = os.listdir(folder)
  data = (folder / name).read_bytes()
  events, offset = [], 0
  while offset < len(data):
    (length,) = struct.unpack('Q', data[offset:offset + 8])
    events.append(event_pb2.Event.FromString(data[offset + 12:offset + 12 + length]))
    offset += 12 + length + 4
  return events


def test_scalars_and_images_are_written_as_tensorboard_reads_them_without_a_thread(tmp_path):
  threads = threading.active_count()
  with event_file.EventWriter(str(tmp_path / 'tb')) as writer:
    writer.add_scalar('train/loss', np.float32(0.5), 3)
    writer.add_image('test/color', np.zeros((4, 5, 3), np.uint8), 4, dataformats='HWC')
    assert threading.active_count() == threads  # Nothing writes behind the caller's back (and dies there).
  header, scalar, image = _events(tmp_path / 'tb')
  assert header.file_version == 'brain.Event:2'
  assert (scalar.step, scalar.summary.value[0].tag, scalar.summary.value[0].simple_value) == (3, 'train/loss', 0.5)
  assert (image.step, image.summary.value[0].image.height, image.summary.value[0].image.width) == (4, 4, 5)


class _FullDisk(io.BytesIO):
  """A file whose writes find the disk full, as a buffered file's flush does."""

  def flush(self):
    if self.getvalue():
      raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_a_write_on_a_full_disk_raises_in_the_caller_naming_the_file(tmp_path, monkeypatch):
  monkeypatch.setattr(record_writer, 'open_file', lambda path: _FullDisk())
  with pytest.raises(OSError) as full:
    event_file.EventWriter(str(tmp_path))  # Its header is flushed at once.
  assert full.value.errno == errno.ENOSPC and full.value.filename.startswith(str(tmp_path / 'events.out.tfevents.'))
