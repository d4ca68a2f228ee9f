"""The viewer's panel (viser's GUI): the runs and their steps, the last frame's size and seconds, what the frames
show and at which sizes, the comparison's layout, the checkpoints, a test view to jump to, and the scene's groups."""

from tools.view import frames, layout, resolution, scene


RUNS_ORDER, FRAME_ORDER = -2., -1.  # The runs first, then each browser's own line about its last frame.


class Panel:
  """The panel of a viewer of runs; actions: 'change'() after a setting changed, 'reload'() when asked for newer
  checkpoints, 'interval'(seconds) for the watcher's interval, 'test_view'(k) to view from test camera k."""

  def __init__(self, server, runs: list, full_rows: int, interval: float, groups: dict, actions: dict):
    gui = server.gui
    self.runs, self.groups = runs, groups
    self._runs_text = gui.add_markdown(self.runs_text(), order=RUNS_ORDER)
    self._output = gui.add_dropdown('Output', frames.OUTPUTS, initial_value='colour')
    self._moving = gui.add_dropdown('Moving size', tuple(resolution.MOVING_CHOICES), initial_value='auto',
                                    hint='auto: the largest that renders within '
                                         f'{resolution.FRAME_BUDGET:g} s; else a fraction of the full size')
    self._rows = gui.add_number('Full size (rows)', full_rows, min=resolution.MIN_ROWS, max=8192, step=1)
    self._layout = self._fraction = None
    if len(runs) > 1:
      self._layout = gui.add_dropdown('Layout', layout.LAYOUTS, initial_value='split')
      self._fraction = gui.add_slider('Split', 0., 1., .01, .5)
    for control in filter(None, (self._output, self._moving, self._rows, self._layout, self._fraction)):
      control.on_update(lambda _: actions['change']())
    self._add_checkpoint_controls(gui, interval, actions)
    self._add_test_view(gui, actions)
    for name, handles in groups.items():
      self._add_group_toggle(gui, name, handles)

  @staticmethod
  def _add_checkpoint_controls(gui, interval: float, actions: dict) -> None:
    reload_button = gui.add_button('Load newer checkpoints')
    reload_button.on_click(lambda _: actions['reload']())
    every = gui.add_number('Look for them every (s, 0: never)', float(interval), min=0., step=1.)
    every.on_update(lambda event: actions['interval'](event.target.value))

  def _add_test_view(self, gui, actions: dict) -> None:
    count = len(self.runs[0].test_set.ids)
    chosen = gui.add_slider('Test view', 0, max(count - 1, 1), 1, 0, disabled=count < 2)
    go = gui.add_button('View from the test camera')
    go.on_click(lambda _: actions['test_view'](int(chosen.value)))

  @staticmethod
  def _add_group_toggle(gui, name: str, handles: list) -> None:
    box = gui.add_checkbox(f'Show {name}', scene.GROUPS[name][1])

    def toggle(_):
      for handle in handles:
        handle.visible = box.value
    box.on_update(toggle)

  def runs_text(self) -> str:
    """The runs and their steps, in Markdown (with two: which shows on the left)."""
    sides = ('left', 'right') if len(self.runs) > 1 else ('',)
    return '  \n'.join(f'{side + ": " if side else ""}**{run.config.expname}** step {run.step}  \n`{run.run_dir}`'
                       for side, run in zip(sides, self.runs))

  def show_runs(self) -> None:
    self._runs_text.content = self.runs_text()

  def show_error(self, text: str) -> None:
    """The runs with a line that went wrong under them (a checkpoint that could not be loaded)."""
    self._runs_text.content = f'{self.runs_text()}  \n**{text}**'

  @staticmethod
  def frame_line(client):
    """show(text): the line about the last frame, in client's panel only (each browser has its own frames)."""
    line = client.gui.add_markdown('no frame yet: the first of each size compiles first (seconds)', order=FRAME_ORDER)

    def show(text: str) -> None:
      line.content = text
    return show

  def options(self) -> frames.Options:
    """The frames.Options the panel holds now."""
    return frames.Options(output=self._output.value, moving=self._moving.value, full_rows=int(self._rows.value),
                          layout=self._layout.value if self._layout else None,
                          fraction=float(self._fraction.value) if self._fraction else .5)
