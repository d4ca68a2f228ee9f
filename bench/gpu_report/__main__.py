"""`python -m bench.gpu_report`, the old name of `python -m lab.gpu_report` (lab/gpu_report.py): runs it for a turn,
saying so."""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

from internal import cli

cli.run_moved('bench.gpu_report', 'lab.gpu_report')
