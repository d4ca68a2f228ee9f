"""Inputs that crashed or trained silently wrong: model sizes, gin includes, host memory, warnings, dead networks."""

import os
import pathlib
import subprocess
import sys

import pytest

import train as train_script
from internal import cli
from internal import configs
from internal.pipeline import loop
from internal.run import stuck
from test_checkpoints import DEMO, TINY, tiny_config
from test_run_dir_errors import _cli, _one_error_line

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('binding, fragment', [
    ('MipNerfModel.num_samples = 0', 'MipNerfModel.num_samples = 0; expected an integer >= 1'),
    ('Config.generated_size = (0, 0)', 'Config.generated_size = (0, 0); expected two positive integers'),
    ('Config.factor = -2', 'Config.factor = -2; expected >= 0'),
    ('FusedDenseTiles.rows = 48', 'FusedDenseTiles.rows = 48; expected a power of two >= 16')])
def test_settings_that_crashed_or_trained_are_one_line_errors(tmp_path, monkeypatch, capsys, binding, fragment):
  status, errout = _cli(monkeypatch, capsys, train_script.main, *TINY, 'Config.max_steps = 3', binding,
                        f"Config.data_dir = '{tmp_path / 'scene'}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'")
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, fragment)
  assert not (tmp_path / 'run').exists() and not (tmp_path / 'scene').exists()  # Refused before any work.


def test_a_missing_gin_include_names_the_including_file_and_the_include(tmp_path, monkeypatch, capsys, caplog):
  inner, outer = tmp_path / 'inner.gin', tmp_path / 'outer.gin'
  inner.write_text("Config.max_steps = 3\ninclude 'nope/missing.gin'\n")
  outer.write_text(f"include '{inner}'\n")
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  status = cli.run(lambda: train_script.main(['--gin_configs', str(outer)]))
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(capsys.readouterr().err, f"gin config '{inner}', line 2: include 'nope/missing.gin' does not exist")
  assert not [r for r in caplog.records if 'Path not found' in r.getMessage()]  # gin's log lines are held back.


def _script(code: str, *argv, cwd=ROOT) -> subprocess.CompletedProcess:
  """python -c code argv... as a user runs it (no FREENERF_DEBUG)."""
  env = {k: v for k, v in os.environ.items() if k != cli.DEBUG_ENV}
  return subprocess.run([sys.executable, '-c', code, *argv], cwd=cwd, env=env, capture_output=True, text=True,
                        timeout=300, check=False)


def test_warnings_print_as_one_line_without_the_source_line(tmp_path):
  (tmp_path / 'file').write_text('not a run directory')
  result = _script('import sys, train; sys.exit(train.cli.run(lambda: train.main(sys.argv[1:])))',
                   '--gin_configs', DEMO, '--gin_bindings', 'Config.freq_reg_end = 900',
                   f"Config.checkpoint_dir = '{tmp_path / 'file'}'")
  assert result.returncode == cli.USAGE_ERROR_STATUS, result.stderr
  lines = result.stderr.splitlines()
  assert ('warning: Config.freq_reg_end = 900 exceeds Config.max_steps = 700: the frequency mask never fully opens '
          'during training') in lines, result.stderr
  assert all(line.startswith(('warning: ', 'error: ')) for line in lines), result.stderr


# Runs train.py's main under an address-space limit 2 GiB above what the process holds once XLA is up: numpy's
# batch (here 4 GiB of pixel indices) runs out before XLA's allocator sees anything.
UNDER_ADDRESS_LIMIT = '''
import resource, sys, jax, train
jax.devices()
with open('/proc/self/status') as f:
  held = next(int(line.split()[1]) * 1024 for line in f if line.startswith('VmSize'))
resource.setrlimit(resource.RLIMIT_AS, (held + 2**31, resource.RLIM_INFINITY))
sys.exit(train.cli.run(lambda: train.main(sys.argv[1:])))
'''


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='reads /proc/self/status')
def test_a_batch_beyond_the_address_space_names_batch_size(tmp_path, scene_dir):
  result = _script(UNDER_ADDRESS_LIMIT, '--gin_configs', DEMO, '--gin_bindings', *TINY,
                   f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'",
                   'Config.batch_size = 536870912')
  assert result.returncode == cli.USAGE_ERROR_STATUS, result.stderr
  _one_error_line(result.stderr, 'out of host memory drawing the training batch (Unable to allocate 4.00 GiB',
                  'lower Config.batch_size = 536870912')


def test_the_stuck_patience_scales_to_short_runs():
  assert stuck.patience(configs.Config(max_steps=100, print_every=5)) == 25  # A quarter of the run.
  assert stuck.patience(configs.Config(max_steps=60, print_every=5)) == 20  # At least 4 windows.
  assert stuck.patience(configs.Config(max_steps=700, print_every=50)) == 200  # The demo: 4 windows of 50.
  assert stuck.patience(configs.Config(max_steps=4000, print_every=100)) == 500  # Long enough: the setting.
  assert stuck.patience(configs.Config(max_steps=100, print_every=5, stuck_warning_steps=10)) == 10
  assert stuck.patience(configs.Config(max_steps=100, stuck_warning_steps=0)) == 0  # Off.


@pytest.mark.parametrize('lr, warns', [(10., True), (None, False)])
def test_a_network_dead_from_the_start_is_named_in_a_short_run(tmp_path, scene_dir, capsys, lr, warns):
  rates = [f'Config.lr_init = {lr}', f'Config.lr_final = {lr}'] if lr else []
  loop.train(tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 60', *rates))
  out = capsys.readouterr().out
  assert ('warning: the training loss set no new best for 20 steps' in out) == warns, out
  assert ('Config.lr_init = 10 ' in out) == warns, out
