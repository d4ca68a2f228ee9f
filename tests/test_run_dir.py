"""Run directories: atomic metadata, the training lock, settings recorded only once a run has started."""

import json
import os
import re
import socket
import subprocess

import pytest

from internal import atomic
from internal.evaluation import learning_curve
from internal.run import checkpoints
from internal.run import run_dir as run_dir_lib
from internal.pipeline import loop
from test_checkpoints import tiny_config


def test_atomic_write_replaces_whole_files_and_leaves_nothing_behind(tmp_path):
  path = tmp_path / 'metrics.json'
  atomic.write_text(path, 'old')
  atomic.write_text(path, 'new')
  assert path.read_text() == 'new' and os.listdir(tmp_path) == ['metrics.json']
  assert oct(path.stat().st_mode & 0o777) == oct(0o644)

  class Unprintable:
    def __str__(self):
      raise RuntimeError('fails halfway')

  with pytest.raises(TypeError):
    atomic.write_text(path, Unprintable())
  assert path.read_text() == 'new' and os.listdir(tmp_path) == ['metrics.json']


def _dead_pid() -> int:
  proc = subprocess.Popen(['true'])
  proc.wait()
  return proc.pid


def test_a_second_training_is_refused_naming_the_holder_and_the_lock_is_released(tmp_path):
  config = tiny_config('s', tmp_path / 'run')
  lock = tmp_path / 'run' / run_dir_lib.LOCK_FILE
  with run_dir_lib.open_run(config) as run_dir:
    holder = json.loads(lock.read_text())
    assert holder['pid'] == os.getpid() and holder['host'] == socket.gethostname()
    started = re.escape(holder['started'])
    with pytest.raises(run_dir_lib.RunDirError, match=rf'being trained by process {os.getpid()} on host .*{started}'):
      with run_dir_lib.open_run(config):
        pass
    assert lock.exists() and run_dir == str(tmp_path / 'run')
  assert not lock.exists()
  with pytest.raises(KeyError):
    with run_dir_lib.open_run(config):
      raise KeyError('a bug in training')
  assert not lock.exists()


def test_the_lock_of_a_killed_process_is_taken_over(tmp_path):
  (tmp_path / 'run').mkdir()
  lock = tmp_path / 'run' / run_dir_lib.LOCK_FILE
  lock.write_text(json.dumps({'pid': _dead_pid(), 'host': socket.gethostname(), 'started': 'earlier'}))
  with run_dir_lib.open_run(tiny_config('s', tmp_path / 'run')):
    assert json.loads(lock.read_text())['pid'] == os.getpid()
  other_host = {'pid': _dead_pid(), 'host': 'elsewhere', 'started': 'earlier'}
  lock.write_text(json.dumps(other_host))  # Another host's process cannot be checked: refused.
  with pytest.raises(run_dir_lib.RunDirError, match="host 'elsewhere'.*delete the lock file"):
    with run_dir_lib.open_run(tiny_config('s', tmp_path / 'run')):
      pass


@pytest.mark.parametrize('content', ['', '{"Config.max_steps": 8', '[1, 2]'])
def test_an_empty_or_corrupt_config_json_is_a_clear_error(tmp_path, content):
  (tmp_path / 'run').mkdir()
  run_dir_lib.record_settings(str(tmp_path / 'run'), tiny_config('s', tmp_path / 'run'))  # A run of ours.
  (tmp_path / 'run' / 'config.json').write_text(content)
  (tmp_path / 'run' / 'checkpoints').mkdir()
  for check in (run_dir_lib.prepare_run_dir, run_dir_lib.check_run_dir):
    with pytest.raises(run_dir_lib.RunDirError, match=r"config\.json' is empty or corrupt.*Config\.overwrite"):
      check(tiny_config('s', tmp_path / 'run'))
  run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path / 'run', 'Config.overwrite = True'))
  assert os.listdir(tmp_path / 'run') == [run_dir_lib.MARKER_FILE]


def test_a_failed_first_start_records_nothing_and_the_corrected_retry_runs(tmp_path, scene_dir):
  run = tmp_path / 'run'
  with pytest.raises(ValueError, match='Config.n_input_views = 99'):
    loop.train(tiny_config(scene_dir, run, 'Config.n_input_views = 99', 'Config.max_steps = 2'))
  assert os.listdir(run) == []
  with pytest.warns(UserWarning, match=r"LPIPS will be null.*no_such\.pkl"):
    loop.train(tiny_config(scene_dir, run, 'Config.max_steps = 2',
                            f"Config.lpips_weights_path = '{tmp_path / 'no_such.pkl'}'"))
  assert run_dir_lib.read_fingerprint(str(run))['Config.n_input_views'] == 8
  assert checkpoints.latest_step(str(run)) == 2 and not (run / run_dir_lib.LOCK_FILE).exists()
  assert sorted(os.listdir(run)) == ['checkpoints', 'config.gin', 'config.json', run_dir_lib.MARKER_FILE,
                                     'learning_curve.csv', learning_curve.CLOCK_FILE, 'tensorboard']  # demo.gin records curves.


def test_training_checks_the_test_split_before_it_starts(tmp_path, scene_dir):
  loop.train(tiny_config(scene_dir, tmp_path / 'first', 'Config.max_steps = 1'))  # Writes the scene.
  missing = scene_dir / 'test' / 'r_5.png'
  os.rename(missing, tmp_path / 'r_5.png')
  try:
    with pytest.raises(FileNotFoundError, match=r'test images are missing.*r_5\.png'):
      loop.train(tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 2'))
  finally:
    os.rename(tmp_path / 'r_5.png', missing)
  assert os.listdir(tmp_path / 'run') == []


def test_the_up_front_check_refuses_what_training_would_and_touches_nothing(tmp_path):
  config = tiny_config('s', tmp_path / 'run')
  run_dir_lib.check_trainable(config)                                  # A new folder: nothing is created.
  assert not (tmp_path / 'run').exists()
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(config), config)
  before = sorted(os.listdir(tmp_path / 'run'))
  run_dir_lib.check_trainable(config)                                  # The same run: resumable.
  other = tiny_config('s', tmp_path / 'run', 'Config.n_input_views = 4')
  for check in (run_dir_lib.check_trainable, run_dir_lib.prepare_run_dir):
    with pytest.raises(run_dir_lib.RunDirError, match=r"different settings \(Config.n_input_views: 8 -> 4\)"):
      check(other)
  assert sorted(os.listdir(tmp_path / 'run')) == before
  run_dir_lib.check_trainable(tiny_config('s', tmp_path / 'run', 'Config.n_input_views = 4', 'Config.overwrite = True'))
  (tmp_path / 'notes').mkdir()
  (tmp_path / 'notes' / 'mine.txt').write_text('user file')
  with pytest.raises(run_dir_lib.RunDirError, match='is not a run of this project'):
    run_dir_lib.check_trainable(tiny_config('s', tmp_path / 'notes'))
