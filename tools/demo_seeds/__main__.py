"""`python -m tools.demo_seeds`, the old name of `python -m lab.demo_seeds` (lab/demo_seeds.py): runs it for a turn,
saying so."""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

from internal import cli

cli.run_moved('tools.demo_seeds', 'lab.demo_seeds')
