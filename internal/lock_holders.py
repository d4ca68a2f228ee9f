"""Holders of this project's lock files (a run directory's lock, a study cell's claim): whether one is gone."""

import os
import socket


def process_gone(holder: dict) -> bool:
  """True when the holder {'host', 'pid', ...} ran on this host and its process no longer exists."""
  if holder.get('host') != socket.gethostname() or not isinstance(holder.get('pid'), int):
    return False
  try:
    os.kill(holder['pid'], 0)
  except ProcessLookupError:
    return True
  except PermissionError:  # Alive, under another user.
    return False
  return False
