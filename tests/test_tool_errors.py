"""tools.mesh, tools.pack_scene, tools.tables, tools.points, tools.synthetic_depth and tools.depth_shape end a bad
input in one `error:` line and exit status 2, as the scripts do (internal/cli.py), when run as
`python -m tools.<name>`."""

import json
import subprocess
import sys

import pytest

from internal import cli
from test_bad_inputs import ROOT
from test_run_dir_errors import _one_error_line
from tools import pack_scene
from tools import synthetic_depth
from tools import tables

# Each tool's __main__ in one interpreter (one start-up of jax), its exit status printed after its stderr.
RUN_AS_MAIN = '''
import json, runpy, sys
for argv in json.loads(sys.argv[1]):
  sys.argv = argv
  try:
    runpy.run_module(argv[0], run_name='__main__', alter_sys=True)
  except SystemExit as stop:
    print(f'status {stop.code}', file=sys.stderr)
'''


def test_each_tool_run_as_a_module_ends_a_bad_input_in_one_line(tmp_path):
  calls = [['tools.tables', str(tmp_path / 'absent'), '--out', str(tmp_path / 'tables')],
           ['tools.pack_scene', '--out', str(tmp_path / 'scene.zip')],
           ['tools.mesh', '--level', 'nan'],
           ['tools.points', '--out', str(tmp_path / 'x.ply'), '--max_points', '0'],
           ['tools.synthetic_depth', '--out', str(tmp_path / 'maps'), '--gamma', '0'],
           ['tools.depth_shape', str(tmp_path / 'absent.toml'), '--export', str(tmp_path / 'shape')]]
  result = subprocess.run([sys.executable, '-c', RUN_AS_MAIN, json.dumps(calls)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, check=False)
  lines = [line for line in result.stderr.splitlines() if line.startswith(('error: ', 'status '))]
  assert lines == [f"error: run root {str(tmp_path / 'absent')!r} does not exist", 'status 2',
                   f"error: --out {str(tmp_path / 'scene.zip')!r}: expected a file name ending in .npz", 'status 2',
                   'error: --level nan: expected a positive finite density (the density is >= 0)', 'status 2',
                   'error: --max_points 0, --path_views 0, --min_views 2: expected >= 1, >= 0, >= 1', 'status 2',
                   'error: --gamma 0.0: expected a finite number > 0', 'status 2',
                   f"error: study file {str(tmp_path / 'absent.toml')!r} does not exist", 'status 2'], \
      result.stderr
  assert 'Traceback' not in result.stderr


def test_tables_names_an_unreadable_metrics_file_and_an_empty_root(tmp_path, capsys):
  (tmp_path / 'run').mkdir()
  status = cli.run(lambda: tables.main([str(tmp_path / 'run'), '--out', str(tmp_path / 'out')]))
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(capsys.readouterr().err, 'no metrics.json under', 'expected run directories evaluated by eval.py')
  for text in ('<<<<<<< HEAD\n{"step": 1}\n=======\n', '[1, 2]'):  # A merge conflict; JSON of another kind.
    (tmp_path / 'run' / 'metrics.json').write_text(text)
    status = cli.run(lambda: tables.main([str(tmp_path / 'run'), '--out', str(tmp_path / 'out')]))
    assert status == cli.USAGE_ERROR_STATUS
    _one_error_line(capsys.readouterr().err, repr(str(tmp_path / 'run' / 'metrics.json')) if text[0] == '<'
                    else str(tmp_path / 'run' / 'metrics.json'))


def test_pack_scene_refuses_an_existing_out_and_a_missing_scene_in_one_line(tmp_path, capsys):
  out = tmp_path / 'scene.npz'
  out.write_bytes(b"the user's")
  status = cli.run(lambda: pack_scene.main(['--out', str(out)]))
  assert status == cli.USAGE_ERROR_STATUS and out.read_bytes() == b"the user's"
  _one_error_line(capsys.readouterr().err, f'--out {str(out)!r} exists; delete it or choose another name')
  bindings = ["Config.dataset_loader = 'llff'", f"Config.data_dir = '{tmp_path / 'absent'}'"]
  status = cli.run(lambda: pack_scene.main(['--gin_bindings', *bindings, '--out', str(tmp_path / 'new.npz')]))
  assert status == cli.USAGE_ERROR_STATUS and not (tmp_path / 'new.npz').exists()
  _one_error_line(capsys.readouterr().err, f"Config.data_dir = {str(tmp_path / 'absent')!r} does not exist")


@pytest.fixture(scope='module')
def small_scene_dir(tmp_path_factory):
  """A generated scene of this module's own (the session's shared one may hold another rig or size)."""
  return tmp_path_factory.mktemp('small_generated_scene')


SEED_EXPECTED = "expected a whole number in [0, 2^63) (a seed of jax's and numpy's random generators)"


@pytest.mark.parametrize('flags, line', [
    (['--blur', '1e400'], '--blur inf: expected a finite number >= 0 (pixels)'),
    (['--gamma', 'nan'], '--gamma nan: expected a finite number > 0'),
    (['--noise', '-1'], '--noise -1.0: expected a finite number >= 0 (of the range)'),
    (['--seed', '-1'], f'--seed -1: {SEED_EXPECTED}'),
    (['--seed', str(2**63)], f'--seed {2**63}: {SEED_EXPECTED}'),
    (['--blur', '41'], "--blur 41.0: expected at most the images' longer side, 40 pixels"),
    (['--noise', '1e38'], '--noise 1e+38: the maps overflow float32; expected a smaller noise (of the range)')])
def test_synthetic_depth_names_the_flag_out_of_its_range_in_one_line(tmp_path, small_scene_dir, capsys, flags, line):
  bindings = [f"Config.data_dir = '{small_scene_dir}'", 'Config.generated_size = (32, 40)']
  argv = ['--gin_bindings', *bindings, '--out', str(tmp_path / 'maps'), *flags]
  assert cli.run(lambda: synthetic_depth.main(argv)) == cli.USAGE_ERROR_STATUS
  err = capsys.readouterr().err
  assert err.splitlines()[-1:] == [f'error: {line}'] and 'warning' not in err and err.count('error') == 1, err
  assert not (tmp_path / 'maps').exists()
