"""The `slow` marker: registered in pytest.ini, and on every test whose call took 25 s or more in the recorded clean-
clone runs (results/ci/*.log's slowest durations), so that the default run, which leaves them out, stays quick."""

import ast
import configparser
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
SLOW_SECONDS = 25.  # Calls of 20-25 s (camera refinement, two devices, the mini configs) stay in the default run.
DURATION = re.compile(r'^([\d.]+)s call\s+(tests/\S+\.py)::(\w+)', re.M)


def slow_calls(log: str) -> set:
  """{(test file, function)} of the calls of SLOW_SECONDS or more in pytest's --durations listing."""
  return {(path, name) for seconds, path, name in DURATION.findall(log) if float(seconds) >= SLOW_SECONDS}


def marked_slow(path: pathlib.Path) -> set:
  """The test functions of a file that carry @pytest.mark.slow (all of them where the module's pytestmark has it)."""
  tree = ast.parse(path.read_text())
  functions = [n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith('test')]
  module_wide = any(isinstance(n, ast.Assign) and any(getattr(t, 'id', '') == 'pytestmark' for t in n.targets)
                    and 'mark.slow' in ast.unparse(n.value) for n in tree.body)
  return {f.name for f in functions if module_wide or any(ast.unparse(d) == 'pytest.mark.slow'
                                                          for d in f.decorator_list)}


def test_slow_calls_reads_the_durations_listing():
  log = ('97.88s call     tests/test_demo.py::test_a\n24.82s setup    tests/test_study.py::test_b\n'
         '24.99s call     tests/test_readme.py::test_c[README.md:4]\n25.00s call     tests/test_kill.py::test_d\n')
  assert slow_calls(log) == {('tests/test_demo.py', 'test_a'), ('tests/test_kill.py', 'test_d')}


def test_the_marker_is_registered_and_strict():
  config = configparser.ConfigParser()
  config.read(ROOT / 'pytest.ini')
  assert config['pytest']['markers'].strip().startswith('slow:')
  assert '--strict-markers' in config['pytest']['addopts'].split()


def test_every_slow_call_of_the_recorded_runs_is_marked():
  logs = '\n'.join(p.read_text() for p in sorted((ROOT / 'results' / 'ci').glob('*.log')))  # CI's and the full run.
  unmarked = sorted(f'{path}::{name}' for path, name in slow_calls(logs) if name not in marked_slow(ROOT / path))
  assert not unmarked, f'calls of {SLOW_SECONDS:.0f} s or more without @pytest.mark.slow: {unmarked}'
