"""kill -9 at random moments (many during checkpoint saves), restart, repeat: the result equals a straight run."""

import os
import subprocess
import sys
import threading
import time

import jax
import numpy as np
import pytest

from internal.run import checkpoints
from internal import datasets
from internal.training import train_step
from internal.pipeline import loop
from conftest import JAX_CACHE
from test_checkpoints import DEMO, ROOT, TINY, _leaves, _read_stderr, tiny_config

STEPS, KILLS = 40, 10
BINDINGS = (f'Config.max_steps = {STEPS}', 'Config.checkpoint_every = 1', 'Config.print_every = 1',
            'Config.checkpoint_keep = 2')


def _newest_saved(folder) -> int:
  """The newest step saved in the checkpoint folder (0 when none)."""
  names = os.listdir(folder) if os.path.isdir(folder) else []
  return max([int(n) for n in names if n.isdigit()], default=0)


def _start(cmd, env):
  """The training subprocess and the list its stderr is collected into."""
  proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
  chunks = []
  threading.Thread(target=_read_stderr, args=(proc, chunks), daemon=True).start()
  return proc, chunks


def _mid_save(folder) -> bool:
  """True when a kill left a save unfinished: an orbax temporary folder or a damaged step folder."""
  names = os.listdir(folder) if os.path.isdir(folder) else []
  return any('tmp' in n or (n.isdigit() and checkpoints.damage(os.path.join(folder, n))) for n in names)


@pytest.mark.slow
def test_sigkill_at_random_moments_then_resume_equals_a_straight_run(tmp_path, scene_dir):
  run = tmp_path / 'killed'
  bindings = TINY + [f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'", *BINDINGS]
  cmd = [sys.executable, 'train.py', '--gin_configs', DEMO, '--gin_bindings', *bindings]
  env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=JAX_CACHE, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0')
  straight = loop.train(tiny_config(scene_dir, tmp_path / 'straight', *BINDINGS)).state
  rng = np.random.default_rng(7)
  kills, mid_save, damaged_reports, tic = 0, 0, 0, time.time()
  while True:
    proc, chunks = _start(cmd, env)
    if kills < KILLS:
      saved = _newest_saved(run / 'checkpoints')
      while _newest_saved(run / 'checkpoints') == saved and proc.poll() is None:  # Until it has saved a step.
        time.sleep(0.02)
      time.sleep(rng.uniform(0., 0.3))
    if kills >= KILLS or proc.poll() is not None:
      assert proc.wait(timeout=120) == 0, ''.join(chunks)[-3000:]
      break
    proc.kill()
    proc.wait()
    kills += 1
    mid_save += _mid_save(run / 'checkpoints')
    damaged_reports += 'is damaged' in ''.join(chunks)
  print(f'{kills} kills ({mid_save} mid-save), {damaged_reports} damaged-checkpoint reports, '
        f'{time.time() - tic:.1f} s')
  assert kills == KILLS and mid_save >= 1
  config = tiny_config(scene_dir, run, *BINDINGS)
  rays = jax.tree.map(lambda x: x[0, 0, :8], datasets.load_dataset('train', config).rays)
  _, resumed = checkpoints.restore_model(config, str(run), rays)
  assert int(resumed.step) == STEPS and isinstance(resumed, train_step.TrainState)
  for a, b in zip(_leaves(resumed), _leaves(straight)):
    np.testing.assert_array_equal(a, b)
