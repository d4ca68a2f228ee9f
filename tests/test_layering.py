"""Layering: the scripts are thin shells over internal/; internal/ and tools/ never import the scripts or bench/,
internal/ never imports tools/, and inside internal/ each stage of the pipeline imports only earlier stages."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPTS = {'train', 'eval', 'render'}
BENCH = 'bench'  # The benchmarks sit on top: they import internal/ and tools/, never the other way.


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


@pytest.mark.parametrize('path', _modules('internal') + _modules('tools'), ids=lambda p: str(p.relative_to(ROOT)))
def test_library_modules_do_not_import_the_benchmarks(path):
  assert BENCH not in imported_modules(path)


@pytest.mark.parametrize('path', _modules('internal'), ids=lambda p: str(p.relative_to(ROOT)))
def test_internal_does_not_import_tools(path):
  assert 'tools' not in imported_modules(path)


# The pipeline's stages in order (docs/design.md). Every module of internal/ belongs to one and imports only its
# own stage and earlier ones: the cameras and how rays follow from them before the datasets that load them, the run
# infrastructure after the step it checkpoints and before the evaluation that
# reads its runs, the training loop (pipeline/) above training and evaluation, the entry points on top.
STAGES = ('records', 'cameras', 'datasets', 'models', 'losses', 'training', 'run', 'evaluation', 'geometry', 'pipeline',
          'entry')
# The modules directly under internal/: plain data and utilities that import nothing of internal/, and the entry
# points of the scripts (the command line, the demo, config loading that validates every stage's settings).
RECORDS = {'rays', 'configs', 'atomic', 'progress', 'environment', 'interrupt', 'lock_holders'}
ENTRY_POINTS = {'cli', 'demo', 'config_loader'}


def stage(module: str) -> str:
  """The stage of a dotted internal module name, e.g. 'internal.models.encoding' -> 'models'."""
  part = module.split('.')[1]
  return 'records' if part in RECORDS else 'entry' if part in ENTRY_POINTS else part


def internal_imports(path: pathlib.Path) -> set:
  """Dotted names of the internal modules a file imports (`from internal import x` and `import internal.x` give
  'internal.x'; `from internal.x import f` gives 'internal.x')."""
  names = set()
  for node in ast.walk(ast.parse(path.read_text(), str(path))):
    if isinstance(node, ast.Import):
      names.update(a.name for a in node.names if a.name.startswith('internal.'))
    elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module.startswith('internal'):
      names.update(f'internal.{a.name}' for a in node.names) if node.module == 'internal' else names.add(node.module)
  return names


def test_internal_imports_sees_every_import_form(tmp_path):
  path = tmp_path / 'm.py'
  path.write_text('import internal.pipeline.loop\nimport internal.models.mlp as mlp\nfrom internal import demo\n'
                  'from internal.run import checkpoints\nimport internalize\ndef f():\n  import internal.cli\n')
  assert internal_imports(path) == {'internal.pipeline.loop', 'internal.models.mlp', 'internal.demo',
                                    'internal.run', 'internal.cli'}


def test_stage_of_a_module():
  assert stage('internal.configs') == 'records' and stage('internal.models.encoding') == 'models'
  assert stage('internal.datasets') == 'datasets' and stage('internal.cli') == 'entry'
  assert stage('internal.pipeline.loop') == 'pipeline' and stage('internal.run.checkpoints') == 'run'


def _staged_modules() -> list:
  """The modules of internal/ (all but its own __init__.py, which imports nothing)."""
  return [p for p in _modules('internal') if p != ROOT / 'internal' / '__init__.py']


def test_every_module_has_a_stage():
  unstaged = {p.relative_to(ROOT).as_posix() for p in _staged_modules()
              if stage(p.relative_to(ROOT).as_posix().removesuffix('.py').replace('/', '.')) not in STAGES}
  assert not unstaged and not internal_imports(ROOT / 'internal' / '__init__.py'), unstaged


@pytest.mark.parametrize('path', _staged_modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_stages_import_only_earlier_stages(path):
  name = path.relative_to(ROOT).as_posix()
  own = STAGES.index(stage(name.removesuffix('.py').replace('/', '.')))
  later = {m for m in internal_imports(path) if STAGES.index(stage(m)) > own}
  assert not later, f'{name} ({STAGES[own]}) imports later stages: {sorted(later)}'


def module_name(path: pathlib.Path) -> str:
  """The dotted name of a file of the repository ('internal/datasets/__init__.py' -> 'internal.datasets')."""
  return path.relative_to(ROOT).as_posix().removesuffix('.py').removesuffix('/__init__').replace('/', '.')


def import_cycle(graph: dict) -> list:
  """A cycle [a, b, ..., a] of the graph {module: modules it imports}, or [] when it has none (depth-first)."""
  done, path = set(), []

  def visit(node):
    if node in path:
      return path[path.index(node):] + [node]
    if node in done:
      return []
    path.append(node)
    found = next((cycle for child in sorted(graph.get(node, ())) for cycle in [visit(child)] if cycle), [])
    path.pop()
    done.add(node)
    return found
  return next((cycle for node in sorted(graph) for cycle in [visit(node)] if cycle), [])


def test_import_cycle_finds_a_cycle_and_none_in_a_tree():
  assert import_cycle({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == ['a', 'b', 'c', 'a']
  assert import_cycle({'a': {'b', 'c'}, 'b': {'c'}, 'c': set()}) == []


def imported_files(path: pathlib.Path, modules: set) -> set:
  """The modules of internal/ (dotted names in modules) a file imports: `from internal.x import y` gives
  'internal.x.y' where y is a module, else 'internal.x' (a package's names, its __init__.py)."""
  names = set()
  for node in ast.walk(ast.parse(path.read_text(), str(path))):
    if isinstance(node, ast.Import):
      names.update(a.name for a in node.names)
    elif isinstance(node, ast.ImportFrom) and node.level == 0:
      names.update(f'{node.module}.{a.name}' if f'{node.module}.{a.name}' in modules else node.module
                   for a in node.names)
  return names & modules


def test_internal_has_no_import_cycles():
  """No module of internal/ imports itself through others (a package's __init__.py importing its own modules is no
  cycle: they import its modules, not the package)."""
  modules = {module_name(p): p for p in _modules('internal')}
  graph = {name: imported_files(path, set(modules)) for name, path in modules.items()}
  assert not import_cycle(graph), ' -> '.join(import_cycle(graph))


def test_every_module_is_checked():
  checked = {p.relative_to(ROOT).as_posix() for p in _modules('internal') + _modules('tools')}
  assert {'internal/pipeline/loop.py', 'internal/evaluation/evaluate.py', 'internal/evaluation/render_path.py',
          'internal/demo.py', 'internal/models/mip_nerf.py', 'tools/study/runner.py', 'tools/tables.py'} <= checked


# The loader files and their registry: the modules every loader shares import none of them, so that a dataset is
# added without touching those (docs/design.md, 'Adding a dataset') and the loaders may import them freely.
LOADER_MODULES = {'dtu', 'llff', 'blender', 'capture', 'generated', 'loader'}


def dataset_imports(path: pathlib.Path) -> set:
  """Names of the internal/datasets modules a file imports (`from internal.datasets import dtu` gives 'dtu')."""
  names = set()
  for node in ast.walk(ast.parse(path.read_text(), str(path))):
    if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module == 'internal.datasets':
      names.update(alias.name for alias in node.names)
    elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module.startswith('internal.datasets.'):
      names.add(node.module.split('.')[2])
  return names


@pytest.mark.parametrize('name', ['packed', 'random_poses', 'base', 'image_io'])
def test_shared_dataset_modules_import_no_loader(name):
  assert not dataset_imports(ROOT / 'internal' / 'datasets' / f'{name}.py') & LOADER_MODULES
