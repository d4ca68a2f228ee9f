"""Test-time pose optimization shows its progress and an estimate before it goes on; one of days is refused."""

import os
import subprocess
import sys

import pytest

from conftest import JAX_CACHE
from internal import cli
from internal import configs
from internal import progress
from internal.evaluation import pose_progress
from internal.pipeline import loop
from test_checkpoints import DEMO, ROOT, TINY, tiny_config

REFINE = ('Config.optimize_cameras = True', 'Config.max_steps = 2', 'Config.compute_lpips = False')


def _steps(test_pose_steps: int, views: int, step_seconds: float) -> None:
  """Runs a PoseProgress through every step of test_pose_steps on views, each step_seconds long."""
  now = [0.]
  with pose_progress.PoseProgress(configs.Config(test_pose_steps=test_pose_steps), views, lambda: now[0]) as on_step:
    for view in range(views):
      for _ in range(test_pose_steps):
        now[0] += step_seconds
        on_step(view, None)


def test_a_test_time_pose_optimization_of_days_is_refused_before_it_goes_on():
  with pytest.raises(ValueError) as refused:
    _steps(10**9, 8, step_seconds=1.)
  assert str(refused.value) == ('Config.test_pose_steps = 1000000000: test-time pose optimization of 8 test views x '
                                '1000000000 steps takes about 254 years more here (1 s a step); expected at most '
                                '1 day (BARF: 100 steps a view)')


def test_a_short_one_says_how_long_it_takes_and_shows_its_progress(capsys):
  _steps(10, 2, step_seconds=2.)
  out, err = capsys.readouterr()
  assert out == 'test-time pose optimization of 2 test views x 10 steps takes about 32 s more here (2 s a step)\n'
  assert 'test-time poses: 100%' in err and '20/20' in err and 'view=2/2' in err


def test_durations_are_in_the_largest_whole_unit():
  assert [progress.duration(s) for s in (45, 720, 12600, 86400, 2 * 86400, 1e9)] == [
      '45 s', '12 min', '3.5 h', '1 day', '2 days', '31.7 years']


def test_eval_with_a_huge_test_pose_steps_refuses_it_in_one_line(scene_dir, tmp_path):
  # It was silent: no bar, no estimate, and no end in sight after 300 s.
  run = tmp_path / 'run'
  loop.train(tiny_config(scene_dir, run, *REFINE))
  env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=JAX_CACHE, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0')
  env.pop(cli.DEBUG_ENV, None)
  done = subprocess.run([sys.executable, 'eval.py', '--gin_configs', DEMO, '--gin_bindings', *TINY, *REFINE,
                         f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'",
                         'Config.test_pose_steps = 1000000000'], cwd=ROOT, env=env, capture_output=True, text=True,
                        check=False, timeout=180)
  assert done.returncode == cli.USAGE_ERROR_STATUS, done.stderr[-3000:]
  last = done.stderr.strip().splitlines()[-1]
  assert last.startswith('error: Config.test_pose_steps = 1000000000: test-time pose optimization of 8 test views '
                         'x 1000000000 steps takes about '), done.stderr[-3000:]
  assert last.endswith('; expected at most 1 day (BARF: 100 steps a view)') and 'years more here' in last
  assert 'test-time poses:' in done.stderr  # Its bar.
