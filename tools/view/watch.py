"""Watching training: the runs' newer checkpoints, picked up every `interval` seconds and when asked, so that a
viewer open beside train.py shows the geometry form as the checkpoints arrive."""

import threading

from internal import cli

DEFAULT_INTERVAL = 10.  # Seconds between two looks for a newer checkpoint (0: only when asked).


class CheckpointWatcher:
  """Looks for newer checkpoints of runs every interval seconds (0: never) and on check(); on_reload(runs) gets the
  runs that loaded one; on_error(message) a user error's line (a checkpoint that cannot be read, a removed run)."""

  def __init__(self, runs: list, interval: float, on_reload, on_error):
    self.runs, self._on_reload, self._on_error = runs, on_reload, on_error
    self._cond = threading.Condition()
    self._interval = float(interval)
    self._stopped = False
    self._check_lock = threading.Lock()
    self._thread = threading.Thread(target=self._loop, daemon=True, name='viewer-checkpoints')
    self._thread.start()

  def set_interval(self, seconds: float) -> None:
    with self._cond:
      self._interval = max(float(seconds), 0.)
      self._cond.notify()

  def stop(self, timeout: float = 60.) -> None:
    with self._cond:
      self._stopped = True
      self._cond.notify()
    self._thread.join(timeout)

  def check(self) -> list:
    """Loads each run's newest checkpoint where it is newer than the shown one; the runs that did."""
    with self._check_lock:
      try:
        reloaded = [run for run in self.runs if run.reload()]
      except cli.USER_ERRORS as err:
        self._on_error(f'checkpoints: {cli.one_line(err)}')
        return []
    if reloaded:
      self._on_reload(reloaded)
    return reloaded

  def _loop(self) -> None:
    while True:
      with self._cond:
        self._cond.wait(self._interval or None)
        if self._stopped:
          return
        due = self._interval > 0
      if due:
        self.check()
