"""The commands that moved to the lab wing (issue 59) keep their old names for a turn: each old name is a shim that
says the new name in one line and runs the moved command; the shims are the only code left at the old paths."""

import ast
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOVED = {'tools.study': 'lab.study', 'tools.study.executor_overhead': 'lab.study.executor_overhead',
         'tools.demo_seeds': 'lab.demo_seeds', 'tools.depth_shape': 'lab.depth_shape',
         'tools.camera_report': 'lab.camera_report', 'bench.ledger': 'lab.ledger',
         'bench.prepare_lease': 'lab.prepare_lease', 'bench.gpu_report': 'lab.gpu_report'}
MOVED_SCRIPTS = {'bench/lease.sh': 'lab/lease.sh', 'bench/gpu_check.sh': 'lab/gpu_check.sh'}


def _run(*argv, env=None) -> subprocess.CompletedProcess:
  return subprocess.run(list(argv), cwd=ROOT, capture_output=True, text=True, timeout=300,
                        env={**os.environ, 'PYTHONPATH': ROOT, **(env or {})}, check=False)


def _shim(old: str) -> str:
  """The shim file of an old module name: <its path>/__main__.py (no file at the old module path itself)."""
  return os.path.join(ROOT, *old.split('.'), '__main__.py')


@pytest.mark.parametrize('old, new', sorted(MOVED.items()))
def test_an_old_command_says_its_new_name_and_runs_it(old, new):
  result = _run(sys.executable, '-m', old, '--help')
  assert result.stderr.splitlines()[0] == (f'note: {old} is now {new} (python -m {new}); the old name goes in a '
                                           'later version')
  assert result.returncode in (0, 2) and 'usage' in (result.stdout + result.stderr).lower()
  assert 'Traceback' not in result.stderr
  assert not os.path.exists(os.path.join(ROOT, *old.split('.')) + '.py')  # Edits to the old file follow the move.


def test_the_old_study_command_is_the_new_one():
  old, new = (_run(sys.executable, '-m', name, '--help') for name in ('tools.study', 'lab.study'))
  assert old.stdout == new.stdout and old.stdout.startswith('usage: python -m lab.study')


@pytest.mark.parametrize('old, new', sorted(MOVED_SCRIPTS.items()))
def test_an_old_script_says_its_new_name_and_runs_it(old, new):
  result = _run('bash', old, env={'OUT': ''})  # Both stop at once on their missing input, naming it.
  lines = result.stderr.splitlines()
  assert lines[0] == f'note: {old} is now {new}; the old name goes in a later version'
  assert result.returncode != 0 and any(('OUT' in line or 'unbound variable' in line) and new in line
                                        for line in lines[1:])


def test_the_shims_are_the_only_code_at_the_old_paths():
  for old, new in MOVED.items():
    with open(_shim(old)) as f:
      body = ast.parse(f.read()).body
    calls = [ast.unparse(node.value) for node in body if isinstance(node, ast.Expr) and isinstance(node.value, ast.Call)]
    assert calls[-1] == f'cli.run_moved({old!r}, {new!r})', old
    assert not any(isinstance(node, (ast.FunctionDef, ast.ClassDef)) for node in body), old
  for folder in ('tools/study', 'tools/demo_seeds', 'tools/depth_shape', 'tools/camera_report', 'bench/ledger',
                 'bench/prepare_lease', 'bench/gpu_report'):
    found = {os.path.relpath(os.path.join(d, n), ROOT) for d, _, names in os.walk(os.path.join(ROOT, folder))
             for n in names if n.endswith('.py')}
    assert found <= {os.path.relpath(_shim(old), ROOT) for old in MOVED}, found
