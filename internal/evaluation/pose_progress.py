"""Test-time pose optimization's progress: a bar over its steps (the view, time left) and, before it goes on, an
estimate of its length, refused beyond MAX_SECONDS (a Config.test_pose_steps typed with a few zeros too many)."""

import time

import jax
import tqdm

from internal import progress

MAX_SECONDS = 24 * 3600.  # Longer is refused: BARF's 100 steps a test view take minutes.
TIMED_STEPS = 3  # Steps timed for the estimate, after the first (which compiles).


class PoseProgress:
  """on_step of camera_evaluation.test_time_poses for Config.test_pose_steps on num_views test views, timed by clock
  (seconds); a context manager that closes its bar."""

  def __init__(self, config, num_views: int, clock=time.perf_counter):
    self.steps, self.num_views, self.clock = config.test_pose_steps, num_views, clock
    self.done, self.tic = 0, 0.
    self.bar = tqdm.tqdm(total=self.steps * num_views, unit='step', desc='test-time poses',
                         **progress.progress_kwargs())

  def __call__(self, view: int, delta) -> None:
    """Counts a finished step of test view `view` (delta: its result); after TIMED_STEPS + 1 steps, the estimate."""
    jax.block_until_ready(delta)  # The bar counts finished steps, so that its rate and time left are true.
    self.done += 1
    if self.done == 1:
      self.tic = self.clock()
    elif self.done == 1 + TIMED_STEPS:
      self._estimate((self.clock() - self.tic) / TIMED_STEPS)
    self.bar.set_postfix(view=f'{view + 1}/{self.num_views}', refresh=False)
    self.bar.update()

  def _estimate(self, step_seconds: float) -> None:
    """Prints how long the steps left take at step_seconds each; ValueError naming Config.test_pose_steps when
    longer than MAX_SECONDS."""
    left = (self.steps * self.num_views - self.done) * step_seconds
    what = (f'test-time pose optimization of {self.num_views} test views x {self.steps} steps takes about '
            f'{progress.duration(left)} more here ({step_seconds:.3g} s a step)')
    if left > MAX_SECONDS:
      raise ValueError(f'Config.test_pose_steps = {self.steps}: {what}; expected at most '
                       f'{progress.duration(MAX_SECONDS)} (BARF: 100 steps a view)')
    tqdm.tqdm.write(what)

  def __enter__(self):
    return self

  def __exit__(self, *exc):
    self.bar.close()
    return False
