"""Layering: the scripts are thin shells over internal/; internal/ and tools/ never import the scripts, and
internal/ never imports tools/."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPTS = {'train', 'eval', 'render'}


def imported_modules(path: pathlib.Path) -> set:
  """Top-level names of the modules a file imports anywhere in it (function bodies included)."""
  names = set()
  for node in ast.walk(ast.parse(path.read_text(), str(path))):
    if isinstance(node, ast.Import):
      names.update(alias.name.split('.')[0] for alias in node.names)
    elif isinstance(node, ast.ImportFrom) and node.level == 0:
      names.add(node.module.split('.')[0])
  return names


def _modules(folder: str) -> list:
  """The .py files under a folder of the repository, as paths relative to it."""
  return sorted((ROOT / folder).rglob('*.py'))


def test_imported_modules_sees_every_import_form(tmp_path):
  path = tmp_path / 'm.py'
  path.write_text('import os.path\nfrom internal import vis\nfrom . import sibling\n'
                  'def f():\n  import train\n  from tools.tables import main\n')
  assert imported_modules(path) == {'os', 'internal', 'train', 'tools'}


@pytest.mark.parametrize('path', _modules('internal') + _modules('tools'), ids=lambda p: str(p.relative_to(ROOT)))
def test_library_modules_do_not_import_the_scripts(path):
  assert not imported_modules(path) & SCRIPTS


@pytest.mark.parametrize('path', _modules('internal'), ids=lambda p: str(p.relative_to(ROOT)))
def test_internal_does_not_import_tools(path):
  assert 'tools' not in imported_modules(path)


def test_every_module_is_checked():
  checked = {p.relative_to(ROOT).as_posix() for p in _modules('internal') + _modules('tools')}
  assert {'internal/training.py', 'internal/evaluation.py', 'internal/render_path.py', 'internal/demo.py',
          'tools/study.py', 'tools/tables.py'} <= checked
