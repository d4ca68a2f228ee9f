"""Every path of this repository that the docs, READMEs, docstrings and study files name exists (no dead paths)."""

import ast
import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOP = ('internal', 'tools', 'bench', 'lab', 'docs', 'configs', 'tests', 'studies', 'results')
PATH = re.compile(r'(?<![\w./-])((?:%s)/[\w./-]*\w)(.?)' % '|'.join(TOP))
# Files docs/design.md tells a user to create when adding a regularizer: examples, not paths of this repository.
EXAMPLES = {'configs/common/my_reg.gin', 'internal/losses/my_reg.py', 'tests/test_my_reg.py'}


def _texts():
  """The repository's files whose text names paths: docs, READMEs, Python, study, gin and shell files (results/
  only by its READMEs)."""
  suffixes = ('.md', '.py', '.toml', '.gin', '.sh', '.sbatch')
  found = [name for name in os.listdir(ROOT) if name.endswith(suffixes)]
  for top in TOP:
    for folder, _, names in os.walk(os.path.join(ROOT, top)):
      found += [os.path.relpath(os.path.join(folder, n), ROOT) for n in names if n.endswith(suffixes)
                and (top != 'results' or n == 'README.md') and '__pycache__' not in folder]
  return sorted(found)


def _defines(module: str, attributes: list) -> bool:
  """Whether a module file defines a dotted attribute: a top-level function, class, assignment or import, and for a
  class, its methods and class attributes ('Config.freq_reg_end')."""
  with open(module) as f:
    body = ast.parse(f.read(), module).body
  for name in attributes:
    found = next((node for node in body if name in _names(node)), None)
    if found is None:
      return False
    body = found.body if isinstance(found, ast.ClassDef) else []
  return True


def _names(node) -> set:
  """The names a module- or class-level statement binds."""
  if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
    return {node.name}
  if isinstance(node, (ast.Assign, ast.AnnAssign)):
    targets = node.targets if isinstance(node, ast.Assign) else [node.target]
    return {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
  if isinstance(node, (ast.Import, ast.ImportFrom)):
    return {(a.asname or a.name).split('.')[0] for a in node.names}
  return set()


def _exists(path: str, named_in: str) -> bool:
  """Whether path exists from the root or beside the file naming it; 'a/b.attr' names an attribute that a/b.py
  defines (a function, class, constant; 'a/b.Class.attr' one of that class's)."""
  for candidate in (path, os.path.join(os.path.dirname(named_in), path)):
    if os.path.exists(os.path.join(ROOT, candidate)):
      return True
    folder, _, name = candidate.rpartition('/')
    module, *attributes = name.split('.')
    source = os.path.join(ROOT, folder, module + '.py')
    if attributes and os.path.isfile(source) and _defines(source, attributes):
      return True
  return False


def named_paths(text: str):
  """The repository paths a text names: patterns, placeholders (*, {x}, <x>, $x) and prefixes ('dtu3_') left out."""
  return {m.group(1) for m in PATH.finditer(text) if not re.search(r'[*{}<>$]', m.group(1) + m.group(2))
          and not m.group(1).endswith('_') and m.group(1) not in EXAMPLES}


def test_the_pattern_takes_paths_and_leaves_patterns_and_placeholders():
  text = ('see internal/models/encoding.py, configs/mini/dtu3_{method}.gin, tests/test_datasets_*.py, '
          "results/<name>/, 'studies/table_' in a and internal/config_loader.validate.")
  assert named_paths(text) == {'internal/models/encoding.py', 'internal/config_loader.validate'}
  gone = os.path.join('internal', 'encoding.py')  # Moved to internal/models/ long ago (joined: not named here).
  assert _exists('internal/config_loader.validate', 'README.md') and not _exists(gone, 'x.md')
  assert _exists('internal/configs.Config.freq_reg_end', 'README.md')


def test_a_module_attribute_that_the_module_lacks_is_dead():
  loader, configs = os.path.join('internal', 'config_loader'), os.path.join('internal', 'configs')  # Joined: not named.
  assert not _exists(loader + '.no_such_function', 'README.md')
  assert not _exists(configs + '.Config.no_such_field', 'README.md')
  assert _exists('internal/datasets/loader.mesh_bounds', 'tools/mesh.py')


@pytest.mark.parametrize('named_in', _texts())
def test_every_named_path_exists(named_in):
  with open(os.path.join(ROOT, named_in), errors='replace') as f:
    dead = sorted(p for p in named_paths(f.read()) if not _exists(p, named_in))
  assert not dead, f'{named_in} names paths that do not exist: {dead}'


def _map_block() -> str:
  """The folder map of docs/design.md: its first code block."""
  with open(os.path.join(ROOT, 'docs', 'design.md')) as f:
    return f.read().split('```text', 1)[1].split('```', 1)[0]


@pytest.mark.parametrize('top', ['internal', 'tools', 'bench', 'lab'])
def test_the_design_map_names_every_module(top):
  block = _map_block()
  unnamed = [os.path.relpath(os.path.join(folder, name), ROOT) for folder, _, names in os.walk(os.path.join(ROOT, top))
             for name in names if name.endswith(('.py', '.sh', '.toml')) and name != '__init__.py'
             and '__pycache__' not in folder and not re.search(r'(?<![\w.])%s\b' % re.escape(name), block)]
  assert not unnamed, f'docs/design.md\'s folder map does not name {unnamed}'
