"""Where a committed result came from: the command that wrote it, the commit, the machine and the date."""

import datetime
import hashlib
import os
import platform
import subprocess
import sys
from typing import Dict, List, Optional, Tuple

from internal import cli


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _git(repo: str, *args) -> Optional[str]:
  """The output of a git command in repo; None outside git."""
  try:
    return subprocess.run(['git', '-C', repo, *args], capture_output=True, text=True, check=True).stdout
  except (OSError, subprocess.CalledProcessError):
    return None


def changed_files(repo: str) -> List[str]:
  """The tracked files of repo that differ from its HEAD ([] outside git): what '+dirty' in a commit means."""
  status = _git(repo, 'status', '--porcelain', '--untracked-files=no')
  return sorted(line[3:] for line in (status or '').splitlines() if line.strip())


def code_state(repo: str) -> Tuple[str, List[str]]:
  """(HEAD of the repository with '+dirty' when tracked files differ from it, those files), from one git status;
  ('unknown', []) outside git."""
  head = _git(repo, 'rev-parse', 'HEAD')
  if head is None:
    return 'unknown', []
  changed = changed_files(repo)
  return head.strip() + ('+dirty' if changed else ''), changed


def git_commit(repo: str) -> str:
  """HEAD of the repository, with '+dirty' when tracked files differ from it ('unknown' outside git)."""
  return code_state(repo)[0]


def file_sha256(path: str) -> str:
  """The SHA-256 of a file's bytes (a study file's identity in an export's provenance)."""
  with open(path, 'rb') as f:
    return hashlib.sha256(f.read()).hexdigest()


def file_at(repo: str, path: str, sha256: str) -> Optional[str]:
  """The text of the file at path (relative to repo) whose bytes have this SHA-256: the file as it is, else its
  newest committed version that has them; None when neither has."""
  full = os.path.join(repo, path)
  if os.path.isfile(full) and file_sha256(full) == sha256:
    with open(full, encoding='utf-8') as f:
      return f.read()
  for commit in (_git(repo, 'log', '--format=%H', '--', path) or '').split():
    shown = subprocess.run(['git', '-C', repo, 'show', f'{commit}:{path}'], capture_output=True, check=False)
    if shown.returncode == 0 and hashlib.sha256(shown.stdout).hexdigest() == sha256:
      return shown.stdout.decode('utf-8')
  return None


def machine() -> Dict[str, object]:
  """The machine and the versions a result was measured with."""
  import jax  # pylint: disable=import-outside-toplevel
  from internal import environment  # pylint: disable=import-outside-toplevel
  devices = jax.devices()
  return {'platform': platform.platform(), 'processor': platform.processor() or platform.machine(),
          'isa': environment.cpu_isa(),
          'cpu_count': os.cpu_count(), 'python': sys.version.split()[0], 'jax': jax.__version__,
          'devices': f'{len(devices)} x {devices[0].device_kind}'}


def cpu_model(cpuinfo: str = '/proc/cpuinfo') -> str:
  """The CPU's model name (Linux), else the platform's processor name."""
  try:
    with open(cpuinfo) as f:
      return next(line.split(':', 1)[1].strip() for line in f if line.startswith('model name'))
  except (OSError, StopIteration):
    return platform.processor() or platform.machine()


def record(command_words) -> dict:
  """{'command' (its absolute paths relative to the repository), 'commit' (HEAD, '+dirty' when tracked files
  differ), 'changed_files' (those files), 'machine' (versions, CPU), 'date'}."""
  commit, changed = code_state(ROOT)
  return {'command': cli.recorded_command(command_words), 'commit': commit, 'changed_files': changed,
          'machine': dict(machine(), cpu=cpu_model()),
          'date': datetime.datetime.now().isoformat(timespec='seconds')}
