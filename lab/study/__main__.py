"""`python -m lab.study`: the study command (runner.py)."""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import sys

from internal import cli
from lab.study import runner

sys.exit(cli.run(runner.main))
