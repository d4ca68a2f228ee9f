"""`python -m tools.depth_shape`, the old name of `python -m lab.depth_shape` (lab/depth_shape.py): runs it for a
turn, saying so."""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

from internal import cli

cli.run_moved('tools.depth_shape', 'lab.depth_shape')
