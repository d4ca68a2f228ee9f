"""Where a committed result came from: the command that wrote it, the commit, the machine and the date."""

import datetime
import os
import platform

from tools import study_export

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def quoted(words) -> str:
  """Words joined as a shell line, those with spaces in double quotes."""
  return ' '.join(f'"{w}"' if ' ' in w else w for w in words)


def cpu_model(cpuinfo: str = '/proc/cpuinfo') -> str:
  """The CPU's model name (Linux), else the platform's processor name."""
  try:
    with open(cpuinfo) as f:
      return next(line.split(':', 1)[1].strip() for line in f if line.startswith('model name'))
  except (OSError, StopIteration):
    return platform.processor() or platform.machine()


def record(command_words) -> dict:
  """{'command', 'commit' (HEAD, '+dirty' when tracked files differ), 'machine' (versions, CPU), 'date'}."""
  return {'command': quoted(command_words), 'commit': study_export.git_commit(ROOT),
          'machine': dict(study_export.machine(), cpu=cpu_model()),
          'date': datetime.datetime.now().isoformat(timespec='seconds')}
