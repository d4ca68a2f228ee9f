"""`python -m tools.study.executor_overhead`, the old name of `python -m lab.study.executor_overhead`
(lab/study/executor_overhead.py): runs it for a turn, saying so."""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

from internal import cli

cli.run_moved('tools.study.executor_overhead', 'lab.study.executor_overhead')
