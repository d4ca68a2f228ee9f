"""The capture folder as the tool owns it: every file it writes is recorded first, and --overwrite removes only those.

MANIFEST (one relative path a line) is appended before each file is written, so that it also covers a run that
stopped half-way; a line ending in '/' records a folder the tool made for a library that names its own files
(structure-from-motion's sfm/: its database, journals and models), removed whole. report.json is written last: a
folder with a manifest and without it holds an unfinished capture, which the tool replaces without --overwrite
(the same command finishes the work). A folder that exists is refused otherwise without --overwrite; with it, the
recorded files are removed (and folders they leave empty), and anything else where the tool would write is named
in an error, never removed.
"""

import errno
import os
import shutil
from typing import Iterable, List

from tools.capture import CaptureError

MANIFEST = '.capture-manifest'
REPORT = 'report.json'  # Written last: its presence marks a finished capture.
# What the tool writes at the top of the folder: none of it may be someone else's.
TOP_LEVEL = ('images', 'images_2', 'images_4', 'images_8', 'sparse/0', 'sfm', REPORT, 'cameras.png')


def recorded(root: str) -> List[str]:
  """The relative paths the manifest of root lists (none without a manifest)."""
  path = os.path.join(root, MANIFEST)
  if not os.path.isfile(path):
    return []
  with open(path, encoding='utf-8') as f:
    return [line.rstrip('\n') for line in f if line.strip()]


def unfinished(root: str) -> bool:
  """True for a folder holding a capture the tool began and did not finish (a manifest, no report.json)."""
  return os.path.isfile(os.path.join(root, MANIFEST)) and not os.path.isfile(os.path.join(root, REPORT))


def _remove_recorded(root: str) -> None:
  """Removes the files and folders the manifest lists, then the folders among their parents that are left empty."""
  folders = set()
  for rel in recorded(root):
    path = os.path.join(root, rel)
    if rel.endswith('/') and os.path.isdir(path) and not os.path.islink(path.rstrip('/')):
      shutil.rmtree(path)
    elif os.path.isfile(path) or os.path.islink(path):
      os.remove(path)
    folders.update(os.path.join(root, p) for p in _parents(rel.rstrip('/')))
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
  """CaptureError when root is a file, or an existing folder without --overwrite that holds no unfinished capture."""
  if os.path.exists(root) and not os.path.isdir(root):
    raise CaptureError(f'--out {root!r} is a file; expected a folder to create')
  if os.path.isdir(root) and not overwrite and not unfinished(root):
    raise CaptureError(f'--out {root!r} exists; choose a new folder, or add --overwrite to replace what '
                       'tools.capture wrote there (nothing else is removed)')


def refuse_input_inside(source: str, root: str) -> None:
  """CaptureError when the input (photos or video) is --out or inside it: the capture would be written over it."""
  inside, out = os.path.realpath(source), os.path.realpath(root)
  if inside == out or inside.startswith(out.rstrip(os.sep) + os.sep):
    raise CaptureError(f'the input {source!r} is inside --out {root!r}, where the capture is written; choose a --out '
                       'outside it (to make a capture again from its own images/, copy them elsewhere first)')


class Output:
  """A capture folder being written: `claim(rel)` records a file and returns its path, its parents made; `writing`
  is the file claimed last (the one being written)."""

  def __init__(self, root: str, overwrite: bool):
    refuse_existing(root, overwrite)
    self.root, self.writing = root, root
    try:
      if os.path.isdir(root):
        _remove_recorded(root)
        foreign = [os.path.join(root, p) for p in TOP_LEVEL if os.path.lexists(os.path.join(root, p))]
        if foreign:
          raise CaptureError(f'--overwrite: {foreign[0]!r} was not written by tools.capture (it is not in '
                             f'{os.path.join(root, MANIFEST)!r}); move it away or choose another --out')
      os.makedirs(root, exist_ok=True)
      open(os.path.join(root, MANIFEST), 'a', encoding='utf-8').close()
    except OSError as err:
      if err.errno == errno.ENOSPC:
        raise
      raise CaptureError(f'--out {root!r} cannot be written: {err.strerror} ({err.filename!r}); choose a folder '
                         'you can write to') from err

  def claim(self, rel: str) -> str:
    """Records the relative path rel as written by the tool; returns its full path (parent folders made)."""
    self.writing = os.path.join(self.root, MANIFEST)
    with open(self.writing, 'a', encoding='utf-8') as f:
      f.write(rel + '\n')
    self.writing = os.path.join(self.root, rel)
    os.makedirs(os.path.dirname(self.writing.rstrip('/')), exist_ok=True)
    return self.writing

  def claim_folder(self, rel: str) -> str:
    """Records the folder rel, made now, as the tool's with everything a library writes into it; returns its path."""
    path = self.claim(rel.rstrip('/') + '/')
    os.makedirs(path, exist_ok=True)
    return path.rstrip('/')
