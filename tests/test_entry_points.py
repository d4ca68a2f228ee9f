"""Every command of the house (`python X.py`, `python -m tools.X`, `lab.X`, `bench.X`) answers Ctrl-C and a user's
error in one line: it sets up interrupt.one_line_when_run before its other imports (which take seconds: Ctrl-C
while they load is one line too) and runs its main through cli.run (cli.run_moved for an old name's shim)."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
HOUSE = ('internal', 'tools', 'bench', 'lab')
SETUP = 'interrupt.one_line_when_run(__name__)'
RUNNERS = {'cli.run', 'cli.run_moved'}


def _is_main_guard(node) -> bool:
  """Whether a statement is `if __name__ == '__main__':`."""
  return (isinstance(node, ast.If) and isinstance(node.test, ast.Compare) and
          ast.unparse(node.test).replace('"', "'") == "__name__ == '__main__'")


def entry_points(root: pathlib.Path = ROOT) -> list:
  """The files of the house run as commands: a package's __main__.py, or a module with `if __name__ == '__main__'`."""
  paths = [p for folder in HOUSE for p in sorted((root / folder).rglob('*.py'))] + sorted(root.glob('*.py'))
  return [p for p in paths if p.name == '__main__.py' or any(map(_is_main_guard, ast.parse(p.read_text()).body))]


def problems(path: pathlib.Path) -> list:
  """What an entry point lacks: the set-up before every import but its own, and main run through cli.run."""
  body = ast.parse(path.read_text()).body
  setup = next((i for i, node in enumerate(body) if ast.unparse(node) == SETUP), None)
  imports = [i for i, node in enumerate(body) if isinstance(node, (ast.Import, ast.ImportFrom))
             and ast.unparse(node) != 'from internal import interrupt']
  found = []
  if setup is None or any(i < setup for i in imports):
    found.append(f'{SETUP} before the other imports')
  calls = {ast.unparse(n.func) for n in ast.walk(ast.Module(body=[s for s in body if _is_main_guard(s)] or body,
                                                            type_ignores=[])) if isinstance(n, ast.Call)}
  if not calls & RUNNERS:
    found.append('main run through cli.run')
  return found


def test_problems_names_what_an_entry_point_lacks(tmp_path):
  path = tmp_path / 'tool.py'
  path.write_text('"""Doc."""\nimport os\nfrom internal import cli\n\nif __name__ == "__main__":\n  main()\n')
  assert entry_points(tmp_path) == [path]
  assert problems(path) == [f'{SETUP} before the other imports', 'main run through cli.run']
  path.write_text('"""Doc."""\n\nfrom internal import interrupt\n' + SETUP + '\nimport os\nfrom internal import cli\n'
                  "if __name__ == '__main__':\n  os._exit(cli.run(main))\n")
  assert problems(path) == []
  (tmp_path / 'library.py').write_text('import os\n')
  assert entry_points(tmp_path) == [path]


def test_the_entry_points_are_found():
  names = {p.relative_to(ROOT).as_posix() for p in entry_points()}
  assert {'train.py', 'eval.py', 'render.py', 'tools/points.py', 'tools/view/__main__.py', 'lab/study/__main__.py',
          'lab/ledger/__main__.py', 'bench/roofline.py', 'tools/study/__main__.py'} <= names


@pytest.mark.parametrize('path', entry_points(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_entry_point_answers_ctrl_c_and_errors_in_one_line(path):
  assert not problems(path), problems(path)
