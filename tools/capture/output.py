"""The capture folder as the tool owns it: every file it writes is recorded first, and --overwrite removes only those.

MANIFEST (one relative path a line) is appended before each file is written, so that it also covers a run that
stopped half-way. A folder that exists is refused without --overwrite; with it, the recorded files are removed
(and folders they leave empty), and anything else where the tool would write is named in an error, never removed.
"""

import os
from typing import Iterable, List

from tools.capture import CaptureError

MANIFEST = '.capture-manifest'
# What the tool writes at the top of the folder: none of it may be someone else's.
TOP_LEVEL = ('images', 'images_2', 'images_4', 'images_8', 'sparse/0', 'sfm', 'report.json', 'cameras.png')


def _recorded(root: str) -> List[str]:
  """The relative paths the manifest of root lists (none without a manifest)."""
  path = os.path.join(root, MANIFEST)
  if not os.path.isfile(path):
    return []
  with open(path, encoding='utf-8') as f:
    return [line.rstrip('\n') for line in f if line.strip()]


def _remove_recorded(root: str) -> None:
  """Removes the files the manifest lists, then the folders among their parents that are left empty."""
  recorded = _recorded(root)
  folders = set()
  for rel in recorded:
    path = os.path.join(root, rel)
    if os.path.isfile(path) or os.path.islink(path):
      os.remove(path)
    folders.update(os.path.join(root, p) for p in _parents(rel))
  for folder in sorted(folders, key=len, reverse=True):
    if os.path.isdir(folder) and not os.listdir(folder):
      os.rmdir(folder)
  if os.path.isfile(os.path.join(root, MANIFEST)):
    os.remove(os.path.join(root, MANIFEST))


def _parents(rel: str) -> Iterable[str]:
  """The folders above a relative path, deepest first ('a/b/c' -> 'a/b', 'a')."""
  parent = os.path.dirname(rel)
  while parent:
    yield parent
    parent = os.path.dirname(parent)


def refuse_existing(root: str, overwrite: bool) -> None:
  """CaptureError when root is a file, or an existing folder without --overwrite."""
  if os.path.exists(root) and not os.path.isdir(root):
    raise CaptureError(f'--out {root!r} is a file; expected a folder to create')
  if os.path.isdir(root) and not overwrite:
    raise CaptureError(f'--out {root!r} exists; choose a new folder, or add --overwrite to replace what '
                       'tools.capture wrote there (nothing else is removed)')


class Output:
  """A capture folder being written: `claim(rel)` records a file and returns its path, its parents made."""

  def __init__(self, root: str, overwrite: bool):
    refuse_existing(root, overwrite)
    if os.path.isdir(root):
      _remove_recorded(root)
      foreign = [os.path.join(root, p) for p in TOP_LEVEL if os.path.lexists(os.path.join(root, p))]
      if foreign:
        raise CaptureError(f'--overwrite: {foreign[0]!r} was not written by tools.capture (it is not in '
                           f'{os.path.join(root, MANIFEST)!r}); move it away or choose another --out')
    os.makedirs(root, exist_ok=True)
    self.root = root

  def claim(self, rel: str) -> str:
    """Records the relative path rel as written by the tool; returns its full path (parent folders made)."""
    with open(os.path.join(self.root, MANIFEST), 'a', encoding='utf-8') as f:
      f.write(rel + '\n')
    path = os.path.join(self.root, rel)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    return path

  def claim_tree(self, rel: str) -> None:
    """Records every file under the folder rel (one another library wrote for the tool, e.g. pycolmap's models)."""
    for folder, _, files in os.walk(os.path.join(self.root, rel)):
      for name in sorted(files):
        self.claim(os.path.relpath(os.path.join(folder, name), self.root))
