"""Names left over from earlier layouts (issue 59): a loader called by the name it had before a rename, and the
study_* aliases that tools/study/runner.py kept from when its siblings were tools/study_*.py."""

import ast
import os
import re

import pytest

from internal.datasets import loader
from tests import test_named_paths

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.parametrize('old, new', sorted(loader.RENAMED.items()))
def test_no_text_calls_a_loader_by_its_earlier_name(old, new):
  stale = []
  for named_in in test_named_paths._texts():  # pylint: disable=protected-access
    with open(os.path.join(ROOT, named_in), errors='replace') as f:
      stale += [f'{named_in}:{n}' for n, line in enumerate(f, 1) if re.search(rf'\b{old} loader\b', line, re.I)]
  assert not stale, f"these lines call the {new!r} loader the {old} loader, its name before the rename: {stale}"


def test_the_study_runner_imports_its_siblings_by_their_own_names():
  path = os.path.join(ROOT, 'tools', 'study', 'runner.py')
  with open(path) as f:
    tree = ast.parse(f.read(), path)
  aliased = [f'{a.name} as {a.asname}' for node in ast.walk(tree)
             if isinstance(node, ast.ImportFrom) and node.module == 'tools.study' for a in node.names if a.asname]
  assert not aliased, f'tools/study/runner.py imports tools.study modules under other names: {aliased}'


def test_no_text_calls_a_budgets_value_the_curves_best_point():
  from tools.study import time_budgets  # pylint: disable=import-outside-toplevel
  assert time_budgets.value_at([(10., 12.), (50., 11.), (90., 13.)], 60.) == 11.  # The last point within, not the best.
  said = []
  for named_in in test_named_paths._texts():  # pylint: disable=protected-access
    with open(os.path.join(ROOT, named_in), errors='replace') as f:
      said += [f'{named_in}:{n}' for n, line in enumerate(f, 1)
               if re.search(r"best curve point|curve's best within", line) and named_in.endswith('.md')]
  assert not said, f'these lines call the value at a budget the best curve point; it is the last one within: {said}'
