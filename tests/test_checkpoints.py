"""Run directories and checkpoints: refusal to overwrite, exact resumption, a checkpoint on SIGTERM."""

import os
import pathlib
import re
import signal
import subprocess
import sys
import threading
import time

import jax
import numpy as np
import pytest

from conftest import JAX_CACHE
from internal import runs
from internal.run import checkpoints
from internal import datasets
from internal.run import run_dir as run_dir_lib
from internal.training import train_step
from internal.pipeline import loop

ROOT = pathlib.Path(__file__).resolve().parents[1]
DEMO = str(ROOT / 'configs' / 'demo.gin')
# A tiny model on a 32 x 40 generated scene: enough to check the machinery quickly on a CPU.
TINY = ['MLP.net_depth = 2', 'MLP.net_width = 32', 'MLP.net_width_viewdirs = 16', 'MipNerfModel.num_samples = 16',
        'Config.generated_size = (32, 40)', 'Config.batch_size = 128', 'Config.print_every = 5',
        'Config.train_render_every = 0', 'Config.render_chunk_size = 1280', 'Config.lr_delay_steps = 10']


def tiny_config(scene_dir, run_dir, *bindings):
  """The demo config shrunk by TINY, on scene_dir, training into run_dir, plus extra bindings."""
  return runs.bind_fresh([DEMO], TINY + [f"Config.data_dir = '{scene_dir}'",
                                        f"Config.checkpoint_dir = '{run_dir}'"] + list(bindings))


def _leaves(state):
  """Host copies of every leaf of a TrainState."""
  return [np.asarray(x) for x in jax.tree.leaves(jax.device_get(state))]


def test_identical_settings_reopen_the_run_and_bookkeeping_may_change(tmp_path):
  first = run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path / 'run'))
  run_dir_lib.record_settings(first, tiny_config('s', tmp_path / 'run'))
  again = run_dir_lib.prepare_run_dir(tiny_config('elsewhere', tmp_path / 'run', 'Config.print_every = 7',
                                                   'Config.checkpoint_every = 3', "Config.expname = 'x'"))
  assert first == again and os.path.isfile(os.path.join(first, run_dir_lib.FINGERPRINT_FILE))


def test_refuses_a_run_directory_with_other_settings(tmp_path):
  run = tmp_path / 'run'
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(tiny_config('s', run)), tiny_config('s', run))
  (run / 'notes.txt').write_text('the user\'s, next to the first run')
  with pytest.raises(run_dir_lib.RunDirError, match=r"run'.*Config\.max_steps: 700 -> 900.*Config\.overwrite"):
    run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 900'))
  with pytest.raises(run_dir_lib.RunDirError, match='MLP.net_width'):
    run_dir_lib.prepare_run_dir(tiny_config('s', run, 'MLP.net_width = 48'))
  run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 900', 'Config.overwrite = True'))
  assert sorted(os.listdir(run)) == [run_dir_lib.MARKER_FILE, 'notes.txt']  # The run's files went, the user's stayed.
  run_dir_lib.record_settings(str(run), tiny_config('s', run, 'Config.max_steps = 900'))
  assert run_dir_lib.read_fingerprint(str(run))['Config.max_steps'] == 900


def test_refuses_a_foreign_non_empty_directory_even_with_overwrite(tmp_path):
  (tmp_path / 'notes.txt').write_text('not a run')
  with pytest.raises(run_dir_lib.RunDirError, match='is not a run of this project'):
    run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path, 'Config.overwrite = True'))
  assert (tmp_path / 'notes.txt').exists()


def test_eval_side_check_names_the_differences(tmp_path):
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path / 'run')),
                              tiny_config('s', tmp_path / 'run'))
  with pytest.raises(run_dir_lib.RunDirError, match='Config.freq_reg_end: 350 -> 0'):
    run_dir_lib.check_run_dir(tiny_config('s', tmp_path / 'run', 'Config.freq_reg_end = 0'))
  with pytest.raises(run_dir_lib.RunDirError, match='holds no run'):
    run_dir_lib.check_run_dir(tiny_config('s', tmp_path / 'other'))


def test_resumed_training_equals_uninterrupted_training(tmp_path, scene_dir):
  n = 6
  bindings = (f'Config.max_steps = {2 * n}', f'Config.checkpoint_every = {n // 2}')
  first = loop.train(tiny_config(scene_dir, tmp_path / 'resumed', *bindings), stop_at_step=n)
  assert int(first.state.step) == n
  assert checkpoints.latest_step(first.run_dir) == n
  resumed = loop.train(tiny_config(scene_dir, tmp_path / 'resumed', *bindings)).state
  straight = loop.train(tiny_config(scene_dir, tmp_path / 'straight', *bindings)).state
  assert int(resumed.step) == int(straight.step) == 2 * n
  for a, b in zip(_leaves(resumed), _leaves(straight)):
    np.testing.assert_array_equal(a, b)
  assert not np.allclose(_leaves(first.state.params)[0], _leaves(resumed.params)[0])
  assert os.path.isfile(os.path.join(first.run_dir, run_dir_lib.GIN_FILE))


def _read_stderr(proc, chunks):
  """Collects a subprocess's stderr (tqdm's progress) into chunks until it closes."""
  for chunk in iter(lambda: os.read(proc.stderr.fileno(), 4096), b''):
    chunks.append(chunk.decode(errors='replace'))


def _steps_done(chunks, total: int) -> int:
  """The highest 'k/total' step count seen in the progress output."""
  return max([int(k) for k in re.findall(rf'(\d+)/{total}\b', ''.join(chunks))] + [0])


def test_the_first_stop_signal_is_kept_and_later_ones_find_the_process_stopping():
  flag = loop.StopFlag()
  with pytest.raises(KeyboardInterrupt):  # Before training stopped: Ctrl-C as ever.
    flag.raise_unless_stopped(signal.SIGINT, None)
  flag(signal.SIGINT, None)
  flag(signal.SIGTERM, None)
  assert flag.signum == signal.SIGINT
  flag.raise_unless_stopped(signal.SIGTERM, None)  # Stopping already: nothing more.


def test_sigterm_saves_a_checkpoint_and_exits_cleanly(tmp_path, scene_dir):
  total = 100000
  bindings = TINY + [f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'",
                     f'Config.max_steps = {total}', 'Config.print_every = 1']
  env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=JAX_CACHE, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0')
  proc = subprocess.Popen([sys.executable, 'train.py', '--gin_configs', DEMO, '--gin_bindings', *bindings],
                          cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
  chunks = []
  reader = threading.Thread(target=_read_stderr, args=(proc, chunks), daemon=True)
  reader.start()
  deadline = time.time() + 120
  while _steps_done(chunks, total) < 3 and proc.poll() is None and time.time() < deadline:
    time.sleep(0.2)
  proc.send_signal(signal.SIGTERM)
  out, _ = proc.communicate(timeout=60)
  reader.join(timeout=5)
  assert proc.returncode == 128 + signal.SIGTERM, ''.join(chunks)[-2000:]
  step = checkpoints.latest_step(str(tmp_path / 'run'))
  assert 3 <= step < total and f'at step {step}' in out.decode()
  config = tiny_config(scene_dir, tmp_path / 'run', f'Config.max_steps = {total}')
  assert run_dir_lib.check_run_dir(config) == str(tmp_path / 'run')
  batch_rays = jax.tree.map(lambda x: x[0, 0, :8], datasets.load_dataset('train', config).rays)
  _, state = checkpoints.restore_model(config, str(tmp_path / 'run'), batch_rays)
  assert int(state.step) == step and isinstance(state, train_step.TrainState)
