"""`python -m tools.study`: the study command (runner.py)."""

import sys

from internal import cli
from tools.study import runner

sys.exit(cli.run(runner.main))
