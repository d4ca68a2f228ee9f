"""lab.study.time_budgets: a metric at training-time budgets from learning curves, on constructed curves."""

import re

import numpy as np
from PIL import Image
import pytest

from lab.study import time_budgets
from lab.study import spec as study_spec
from lab.study import stats as study_stats

STUDY = '''
name = "budget"
seeds = 4
[methods.fast]
configs = ["configs/demo.gin"]
[methods.slow]
configs = ["configs/demo.gin"]
[scenes.s1]
[plot]
metrics = ["psnr"]
budgets = [5, 25, 60]
'''
T_975_DF3 = 3.182446305284263  # Student's t quantile (two-sided 95%, 3 degrees of freedom), from a table.
T_99167_DF3 = 4.856657  # The same at two-sided 1 - 0.05 / 3 (Bonferroni over 3 pairs), from a table.
FAST = {'0': 12., '1': 12.5, '2': 11.5, '3': 12.2}  # fast's PSNR from 10 s on; slow's is fast's + 3 from 40 s.


def _curve_rows():
  """fast: points at 10, 20, 30 s (its final value from the first); slow: 8 below fast at 20 s, 3 above at 40 s."""
  rows = []
  for seed, value in FAST.items():
    rows += [{'method': 'fast', 'scene': 's1', 'seed': seed, 'step': 100 * k, 'seconds': 10. * k, 'psnr': value}
             for k in (1, 2, 3)]
    rows += [{'method': 'slow', 'scene': 's1', 'seed': seed, 'step': 100, 'seconds': 20., 'psnr': value - 8.},
             {'method': 'slow', 'scene': 's1', 'seed': seed, 'step': 200, 'seconds': 40., 'psnr': value + 3.}]
  return rows


def test_value_at_takes_the_last_point_within_the_budget():
  curve = [(10., 1.), (20., 2.), (30., 3.)]
  assert time_budgets.value_at(curve, 9.9) is None
  assert time_budgets.value_at(curve, 10.) == 1. and time_budgets.value_at(curve, 29.) == 2.
  assert time_budgets.value_at(curve, 1e9) == 3.


def test_each_budget_names_the_best_setting_with_its_spread_and_paired_interval():
  study = study_spec.parse(STUDY, 'budget.toml')
  assert study.plot.budgets == (5., 25., 60.)
  rows = time_budgets.budget_rows(study, _curve_rows(), 'psnr', study.plot.budgets)
  assert [r['budget_s'] for r in rows] == [25., 60.]  # Nothing was recorded within 5 s.
  at_25, at_60 = rows
  values = np.array(list(FAST.values()))
  assert at_25['best'] == 'fast' and at_25['runner_up'] == 'slow' and at_25['n'] == 4
  assert at_25['mean'] == pytest.approx(values.mean()) and at_25['std'] == pytest.approx(values.std(ddof=1))
  # The paired difference is 8 on every seed: no spread, a zero-width interval that excludes 0.
  assert at_25['mean_a_minus_b'] == pytest.approx(8.) and at_25['ci_low'] == pytest.approx(8.)
  assert at_25['verdict'] == 'fast better'
  assert at_60['best'] == 'slow' and at_60['mean'] == pytest.approx(values.mean() + 3.)
  assert at_60['verdict'] == 'slow better'


def test_a_noisy_difference_is_undecided_with_the_t_interval():
  study = study_spec.parse(STUDY, 'budget.toml')
  rows = _curve_rows()
  noise = {'0': 4., '1': -3.5, '2': 2., '3': -2.8}  # slow - fast at 60 s becomes 3 + noise.
  for row in rows:
    if row['method'] == 'slow' and row['seconds'] == 40.:
      row['psnr'] += noise[row['seed']]
  (row,) = time_budgets.budget_rows(study, rows, 'psnr', (60.,))
  differences = np.array([3. + n for n in noise.values()])
  half = T_975_DF3 * differences.std(ddof=1) / 2.
  assert row['best'] == 'slow' and row['mean_a_minus_b'] == pytest.approx(differences.mean())
  assert (row['ci_low'], row['ci_high']) == pytest.approx((differences.mean() - half, differences.mean() + half))
  assert row['verdict'].startswith(study_stats.UNDECIDED)
  assert '**UNDECIDED' in time_budgets.budget_markdown([row])


def test_curves_against_seconds_are_plotted_and_budgets_written(tmp_path):
  study = study_spec.parse(STUDY, 'budget.toml')
  written = time_budgets.write_budget_results(study, _curve_rows(), str(tmp_path), ('psnr', 'psnr_masked'))
  assert [p.split('/')[-1] for p in written] == ['psnr_vs_seconds.png', 'budgets.md']
  with Image.open(tmp_path / 'psnr_vs_seconds.png') as image:
    assert image.format == 'PNG' and image.size == (640, 440)
  table = (tmp_path / 'budgets.md').read_text()
  assert re.search(r'\| 25 \| psnr \| fast \| 12\.05 \|', table) and re.search(r'\| 60 \| psnr \| slow \|', table)


@pytest.mark.parametrize('budgets', ['[60, 5]', '[0]', '["1 min"]'])
def test_bad_budgets_are_named(budgets):
  with pytest.raises(study_spec.StudyError, match=r'plot\.budgets'):
    study_spec.parse(STUDY.replace('budgets = [5, 25, 60]', f'budgets = {budgets}'), 'budget.toml')


def test_with_three_settings_the_interval_holds_for_all_three_pairs_as_the_best_is_chosen_from_them():
  third = '[methods.third]\nconfigs = ["configs/demo.gin"]\n[scenes.s1]'
  study = study_spec.parse(STUDY.replace('[scenes.s1]', third), 'budget.toml')
  rows = _curve_rows()
  noise = {'0': 4., '1': -3.5, '2': 2., '3': -2.8}
  for row in list(rows):
    if row['method'] == 'slow' and row['seconds'] == 40.:
      row['psnr'] += noise[row['seed']]
    if row['method'] == 'fast':
      rows.append(dict(row, method='third', psnr=row['psnr'] - 5.))
  (row,) = time_budgets.budget_rows(study, rows, 'psnr', (60.,))
  differences = np.array([3. + n for n in noise.values()])
  half = T_99167_DF3 * differences.std(ddof=1) / 2.  # 3 pairs: each at 1 - 0.05 / 3.
  assert row['best'] == 'slow' and row['runner_up'] == 'fast'
  assert (row['ci_low'], row['ci_high']) == pytest.approx((differences.mean() - half, differences.mean() + half))
  assert time_budgets.selection_level(2) == pytest.approx(0.95)
  assert time_budgets.selection_level(3) == pytest.approx(1 - 0.05 / 3)
