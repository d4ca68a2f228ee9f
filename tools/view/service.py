"""The frames of one browser, rendered on a thread of its own so that the websocket stays responsive.

Every request (the camera moved, a setting changed, a newer checkpoint arrived) replaces the one before it: the
thread renders the newest request at the moving size at once, then at the full size once no newer request came
for REST seconds; a request that a newer one overtook is dropped, and a frame being rendered stops between two
bands of rows when one arrives (frames.Cancelled). Moving frames travel as JPEG, full-size ones as PNG, so that
what rests on the screen is the render's exact pixels.
"""

import threading
import time

from tools.view import frames, resolution

REST = .3  # Seconds without a newer request after which the full size is rendered.
JPEG_QUALITY = 90


class ClientView:
  """The render thread of one browser. runs: the shown Runs; options(): the current frames.Options; send(image,
  format): shows a frame; report(text): the line about the last frame."""

  def __init__(self, runs: list, options, send, report):
    self.runs, self._options, self._send, self._report = runs, options, send, report
    self._cond = threading.Condition()
    self._view = None
    self._generation = self._moving_done = self._full_done = 0
    self._requested_at = 0.
    self._stopped = False
    self.seconds_per_ray = 0.
    self._thread = threading.Thread(target=self._loop, daemon=True, name='viewer-render')
    self._thread.start()

  def request(self, view: frames.View = None) -> None:
    """A new frame: of view, or (None) of the last view again (a setting or the checkpoint changed). The view
    shown already is no new request (a browser sends its camera again now and then without moving it)."""
    with self._cond:
      if view is not None and view == self._view:
        return
      self._view = view or self._view
      self._generation += 1
      self._requested_at = time.monotonic()
      self._cond.notify()

  def stop(self, timeout: float = 60.) -> None:
    """Ends the thread, the frame it renders stopped at its next band (an exit in the middle of a compiled call
    would abort the process)."""
    with self._cond:
      self._stopped = True
      self._generation += 1
      self._cond.notify()
    self._thread.join(timeout)

  def _next(self):
    """(full size?, view, generation) of the next frame to render, waiting for one; None once stopped."""
    with self._cond:
      while not self._stopped:
        if self._view is not None and self._moving_done < self._generation:
          return False, self._view, self._generation
        if self._view is not None and self._full_done < self._generation:
          wait = self._requested_at + REST - time.monotonic()
          if wait <= 0:
            return True, self._view, self._generation
          self._cond.wait(wait)
        else:
          self._cond.wait()
      return None

  def _loop(self) -> None:
    while True:
      task = self._next()
      if task is None:
        return
      full, view, generation = task
      try:
        self._render(full, view, generation)
      except frames.Cancelled:
        pass

  def _render(self, full: bool, view: frames.View, generation: int) -> None:
    """Renders and sends one frame of view (generation's request), at the full or the moving size."""
    options = self._options()
    rows = options.full_rows if full else resolution.moving_rows(options.moving, options.full_rows,
                                                                 self.seconds_per_ray, view.aspect)
    compiled_before = [run.compiled_shapes() for run in self.runs]
    start = time.perf_counter()
    image, count = frames.render_frame(self.runs, view, rows, options, lambda: self._generation != generation)
    seconds = time.perf_counter() - start
    if compiled_before == [run.compiled_shapes() for run in self.runs]:  # A compile's seconds say nothing of speed.
      self.seconds_per_ray = resolution.updated_speed(self.seconds_per_ray, seconds, count)
    is_full = rows == options.full_rows
    self._send(image, 'png' if is_full else 'jpeg')
    with self._cond:
      self._moving_done = max(self._moving_done, generation)
      if is_full:
        self._full_done = max(self._full_done, generation)
    steps = ' / '.join(f'step {run.step}' for run in self.runs)
    self._report(f'{steps}: {image.shape[0]} x {image.shape[1]} in {seconds:.2f} s'
                 f'{" (full size)" if is_full else " (moving)"}')
