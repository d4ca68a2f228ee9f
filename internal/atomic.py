"""Atomic file writes: a reader (or a crash) sees the old content or the new one, never a partial file."""

import contextlib
import os
import tempfile


def write_text(path, text: str) -> None:
  """Writes text to path atomically (see _write)."""
  _write(path, text, 'w', newline='')


def write_bytes(path, data: bytes) -> None:
  """Writes data to path atomically (see _write)."""
  _write(path, data, 'wb')


def _write(path, content, mode: str, **open_kwargs) -> None:
  """Writes content to path through a temporary file in the same folder, fsync and os.replace."""
  path = os.fspath(path)
  fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path) or '.', prefix=f'.{os.path.basename(path)}.',
                             suffix='.tmp')
  try:
    with os.fdopen(fd, mode, **open_kwargs) as f:
      f.write(content)
      f.flush()
      os.fsync(f.fileno())
    os.chmod(tmp, 0o644)  # mkstemp creates 0600; metadata files are as readable as any other output.
    os.replace(tmp, path)
  except BaseException as err:
    with contextlib.suppress(FileNotFoundError):
      os.unlink(tmp)
    if isinstance(err, OSError) and err.filename is None:  # A failed write or fsync: name the file (disk full).
      raise OSError(err.errno, err.strerror, path) from err
    raise
