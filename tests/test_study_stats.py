"""tools.study.stats and the seed axis of study files: statistics checked on constructed results with known values."""

import csv
import json
import math
import pathlib
import re

import matplotlib.pyplot as plt
import numpy as np
from PIL import Image
import pytest

from tools.study import looks as study_looks
from tools.study import reuse
from tools.study import runner as study_lib
from tools.study import plots as study_plots
from tools.study import spec as study_spec
from tools.study import stats as study_stats
from tools.study import time_budgets

SEEDED = '''
name = "seeded"
seeds = 3
[methods.freenerf]
configs = ["configs/demo.gin"]
[methods.mipnerf]
configs = ["configs/demo.gin"]
[scenes.s1]
[scenes.s2]
[plot]
metrics = ["psnr", "lpips"]
'''
ROOT = pathlib.Path(__file__).resolve().parents[1]
T_975 = {3: 3.182446305284263, 4: 2.7764451051977987}  # Student's t quantiles from a table (df: value).


def _rows(offsets, noise=((0., .3, -.2), (.1, -.4, .25))):
  """Rows of SEEDED: mipnerf psnr 10 + noise, freenerf = mipnerf + offsets[scene][seed]; lpips = psnr / 100."""
  rows = []
  for s, scene in enumerate(('s1', 's2')):
    for seed in range(3):
      base = 10. + noise[s][seed]
      for method, value in (('mipnerf', base), ('freenerf', base + offsets[s][seed])):
        rows.append({'method': method, 'scene': scene, 'seed': str(seed), 'psnr': value, 'lpips': value / 100.})
  return rows


@pytest.fixture(name='study')
def fixture_study():
  return study_spec.parse(SEEDED, 'seeded.toml')


def test_seeds_become_an_axis_binding_both_seeds_and_stay_out_of_expname(study):
  axis = study.axes[-1]
  assert axis.name == 'seed' and [p.label for p in axis.points] == ['0', '1', '2']
  assert axis.points[2].bindings == ('Config.jax_rng_seed = 2', 'Config.np_rng_seed = 2')
  cell = study_spec.cells(study)[2]
  assert cell.cell_id == 'freenerf__s1__seed=2' and cell.expname == 'freenerf'
  assert study.compare == (study_spec.Compare('method', 'mipnerf', 'freenerf'),)


def test_seed_lists_and_explicit_comparisons():
  study = study_spec.parse(SEEDED.replace('seeds = 3', 'seeds = [7, 11]')
                           + '[[compare]]\na = "freenerf"\nb = "mipnerf"\n', 'x.toml')
  assert [p.label for p in study.axes[-1].points] == ['7', '11']
  assert study.compare == (study_spec.Compare('method', 'freenerf', 'mipnerf'),)


@pytest.mark.parametrize('extra, message', [
    ('seeds = 0', 'seeds: 0; expected a count >= 1'),
    ('seeds = [1, 1]', 'expected a count >= 1 or a list of distinct integers'),
    ('seeds = ["a"]', 'expected a count >= 1 or a list of distinct integers'),
    ('seeds = 2\n[[axis]]\nname = "seed"\nbinding = "Config.jax_rng_seed"\nvalues = [1]', 'also has an axis'),
    ('[[compare]]\na = "freenerf"\nb = "nerf"', "compare[0].b: 'nerf' is not a label of method"),
    ('[[compare]]\na = "freenerf"\nb = "freenerf"', 'a and b are both'),
    ('[[compare]]\naxis = "seed"\na = "0"\nb = "1"', 'an axis other than the seed'),
])
def test_bad_seeds_and_comparisons_name_the_key(extra, message):
  text = SEEDED.replace('seeds = 3\n', '')
  head, tail = text.split('[methods.freenerf]')
  with pytest.raises(study_spec.StudyError, match=re.escape(message)):
    study_spec.parse(head + extra + '\n[methods.freenerf]' + tail, 'bad.toml')


def test_t_interval_against_the_table():
  mean, low, high = study_stats.t_interval([1., 2., 3., 4.])
  half = T_975[3] * math.sqrt(5. / 3.) / 2.  # sample std of 1..4 is sqrt(5/3); se = std / sqrt(4).
  assert mean == 2.5 and low == pytest.approx(2.5 - half, rel=1e-9) and high == pytest.approx(2.5 + half)
  assert study_stats.t_interval([0.7]) == (0.7, None, None)


def test_t_interval_covers_the_true_mean_95_percent_of_the_time():
  rng = np.random.default_rng(0)
  samples = rng.normal(0.5, 2., (4000, 5))
  covered = [low <= 0.5 <= high for low, high in (study_stats.t_interval(list(s))[1:] for s in samples)]
  assert np.mean(covered) == pytest.approx(0.95, abs=0.012)


def test_summary_gives_mean_std_and_n_over_seeds(study):
  summary = study_stats.summarize(study, _rows(((1., 2., 3.), (0., 0., 0.))), 'psnr')
  s1 = next(s for s in summary if s['method'] == 'freenerf' and s['scene'] == 's1')
  assert s1['n'] == 3 and s1['mean'] == pytest.approx((11. + 12.3 + 12.8) / 3.)
  assert s1['std'] == pytest.approx(np.std([11., 12.3, 12.8], ddof=1))
  assert 'seed' not in s1 and len(summary) == 4


def test_paired_difference_over_seeds_and_scenes(study):
  offsets = ((-1., -2., -3.), (-1.5, -2.5, -2.))
  comparison, = study_stats.compare(study, _rows(offsets), 'psnr')
  differences = [1., 2., 3., 1.5, 2.5, 2.]  # mipnerf - freenerf, pair by pair.
  half = T_975.get(5, 2.5705818366147395) * np.std(differences, ddof=1) / math.sqrt(6)
  assert comparison.n == 6 and comparison.mean == pytest.approx(2.)
  assert comparison.low == pytest.approx(2. - half) and comparison.high == pytest.approx(2. + half)
  assert comparison.verdict == 'mipnerf better'
  lpips, = study_stats.compare(study, _rows(offsets), 'lpips')  # Lower is better: mipnerf's is higher.
  assert lpips.verdict == 'freenerf better'


def test_an_interval_containing_zero_is_undecided(study):
  comparison, = study_stats.compare(study, _rows(((1., -1., 2.), (-2., 1., -.5))), 'psnr')
  assert comparison.low < 0 < comparison.high
  assert comparison.verdict == 'UNDECIDED: the 95% interval contains 0'
  one = [r for r in _rows(((1., 1., 1.), (1., 1., 1.))) if r['seed'] == '0' and r['scene'] == 's1']
  assert study_stats.compare(study, one, 'psnr')[0].verdict == 'UNDECIDED: 1 pair, no interval'


def test_unmatched_or_missing_rows_make_no_pair(study):
  rows = [r for r in _rows(((1., 1., 1.), (1., 1., 1.))) if not (r['method'] == 'freenerf' and r['seed'] == '2')]
  rows[0]['psnr'] = ''  # Not finished: left out, with its partner.
  assert study_stats.compare(study, rows, 'psnr')[0].n == 3


def test_statistics_files_and_plots(study, tmp_path):
  rows = _rows(((1., -1., 2.), (-2., 1., -.5)))
  written = study_lib.write_statistics(study, rows, str(tmp_path))
  assert sorted(p.rsplit('/', 1)[1] for p in written) == ['comparisons.csv', 'comparisons.md', 'summary.csv']
  markdown = (tmp_path / 'comparisons.md').read_text()
  assert '**UNDECIDED: the 95% interval contains 0**' in markdown and '| 6 |' in markdown
  plots = study_plots.write_plots(study, rows, str(tmp_path))
  assert {p.rsplit('/', 1)[1] for p in plots} >= {'compare_psnr.png', 'compare_lpips.png'}
  assert Image.open(tmp_path / 'compare_psnr.png').size == (640, 440)


def test_learning_curves_over_seeds_are_one_mean_line_per_setting(study):
  rows = [{'method': 'freenerf', 'scene': 's1', 'seed': str(seed), 'step': step, 'psnr': step / 100. + seed}
          for seed in range(3) for step in (100, 200)]
  lines = study_plots._series(study, rows, 'step', 'psnr', None)
  fig, ax = study_plots.curve_figure(study, lines)
  try:
    (mean,) = ax.containers                                 # One line: the mean with its error bars.
    assert mean.get_label() == 'freenerf s1 (mean +-1 std, n=3)'
    np.testing.assert_allclose(mean.lines[0].get_xydata(), [[100, 2.], [200, 3.]])
  finally:
    plt.close(fig)


def test_seeds_are_placed_as_categories_in_their_order():
  study = study_spec.parse(SEEDED.replace('seeds = 3', 'seeds = [20200823, 1, 2]'), 'seeded.toml')
  positions, ticks = study_plots._axis_positions(study, study_spec.SEED_AXIS)
  assert positions == {'20200823': 0., '1': 1., '2': 2.} and ticks == ['20200823', '1', '2']


@pytest.mark.parametrize('use', [study_stats.compare, study_stats.summarize])
def test_two_rows_of_one_setting_and_seed_are_refused_naming_them(study, use):
  rows = _rows(((1., 1., 1.), (1., 1., 1.)))
  twice = dict(rows[2], psnr=7.5)  # mipnerf on s1, seed 1 again, with another value.
  with pytest.raises(ValueError, match=r'^two results for method mipnerf, scene s1, seed 1 \(psnr: 10.3 and 7.5\); '
                                       'expected one row per setting and seed'):
    use(study, rows + [twice], 'psnr')
  assert use(study, rows + [dict(twice, psnr='')], 'psnr')  # An unfinished row has no value to count twice.


def test_looking_at_3_seeds_then_5_errs_near_9_percent_and_the_corrected_looks_at_most_5():
  """A null paired difference read at 3 seeds and, undecided, at 5: at 95% a look declares a difference 8.7% of the
  time; with the study's looks = [3, 5] each interval is at 97.5% and both looks together err at most 5%."""
  study = study_spec.parse(SEEDED.replace('seeds = 3', 'seeds = 5\nlooks = [3, 5]'), 'seeded.toml')
  assert study_stats.looks(study) == (3, 5) and study_stats.look_level(study) == pytest.approx(.975)
  differences = np.random.default_rng(0).normal(0., 1., (5000, 5))

  def declares(sample, level):
    return any(not low <= 0. <= high for _, low, high in (study_stats.t_interval(list(sample[:n]), level)
                                                          for n in (3, 5)))

  plain = np.mean([declares(s, study_stats.LEVEL) for s in differences])
  corrected = np.mean([declares(s, study_stats.look_level(study)) for s in differences])
  assert .075 < plain < .1 and corrected <= .05, (plain, corrected)


def _decided_at_95_only(study):
  """Rows of SEEDED whose psnr comparison excludes 0 at 95% but not at 97.5% (6 pairs, t = 2.87)."""
  rows = _rows(((1.5, -.1, 1.6), (.2, 1.7, .6)))
  difference = [1.5, -.1, 1.6, .2, 1.7, .6]
  t = np.mean(difference) / (np.std(difference, ddof=1) / math.sqrt(6))
  assert 2.571 < t < 3.163, t  # Student's t at 95% and 97.5% per look, 5 degrees of freedom.
  return rows


def test_a_study_read_at_several_seed_counts_corrects_every_interval_and_says_so(study, tmp_path):
  rows = _decided_at_95_only(study)
  comparison, = study_stats.compare(study, rows, 'psnr')
  assert comparison.verdict == 'freenerf better'
  looked = study_spec.parse(SEEDED.replace('seeds = 3', 'seeds = 3\nlooks = [2, 3]'), 'seeded.toml')
  comparison, = study_stats.compare(looked, rows, 'psnr')
  assert comparison.verdict == 'UNDECIDED: the 97.5% interval contains 0' and comparison.level == .975
  study_lib.write_statistics(looked, rows, str(tmp_path))
  markdown = (tmp_path / 'comparisons.md').read_text()
  assert 'corrected for 2 looks: read at 2 and 3 seeds' in markdown and '| 97.5% interval |' in markdown
  study_lib.write_statistics(study, rows, str(tmp_path))
  assert 'one look: read at 3 seeds only' in (tmp_path / 'comparisons.md').read_text()
  assert time_budgets.selection_level(3, looks=2) == pytest.approx(1. - .05 / 3 / 2)  # 3 pairs of settings, 2 looks.


def test_the_runner_records_a_look_at_each_finished_seed_count_and_corrects_for_it(study, tmp_path):
  rows = [dict(r, status='done') for r in _decided_at_95_only(study)]
  study_looks.record_if_finished(study, str(tmp_path), rows[:-1] + [dict(rows[-1], status='missing')])
  assert not (tmp_path / study_looks.FILE).exists()           # Not finished: no look recorded.
  study_looks.record_if_finished(study, str(tmp_path), rows)
  assert json.loads((tmp_path / study_looks.FILE).read_text()) == {'seed_counts': [3]}
  more = study_spec.parse(SEEDED.replace('seeds = 3', 'seeds = 5'), 'seeded.toml')  # Seeds added after looking.
  assert study_stats.looks(study_looks.with_recorded(more, str(tmp_path))) == (3, 5)
  assert study_stats.looks(study_looks.with_recorded(study, str(tmp_path))) == (3,)
  declared = study_spec.parse(SEEDED.replace('seeds = 3', 'seeds = 3\nlooks = [2, 3]'), 'seeded.toml')
  study_looks.record_if_finished(declared, str(tmp_path), rows)  # Kept with the record, so that exports carry it.
  assert study_looks.recorded(str(tmp_path)) == [2, 3]
  (tmp_path / study_looks.FILE).write_text('{"seed_counts": "3"}')
  with pytest.raises(ValueError, match=r'looks.json: .*expected \{"seed_counts": \[n, ...\]\}'):
    study_looks.recorded(str(tmp_path))


@pytest.mark.parametrize('extra, message', [
    ('looks = [3, 2]', 'looks: [3, 2]; expected increasing seed counts >= 1'),
    ('looks = [2]', "looks: [2]; expected increasing seed counts >= 1 at which the comparisons were read, the last "
                    "the study's 3 seeds"),
    ('looks = [0, 3]', 'looks: [0, 3]; expected increasing'),
    ('looks = "3"', "looks: '3'; expected increasing"),
])
def test_bad_looks_name_the_key(extra, message):
  with pytest.raises(study_spec.StudyError, match=re.escape(message)):
    study_spec.parse(SEEDED.replace('seeds = 3', f'seeds = 3\n{extra}'), 'bad.toml')
  with pytest.raises(study_spec.StudyError, match='looks: the study has no seeds'):
    study_spec.parse(SEEDED.replace('seeds = 3', 'looks = [3]'), 'bad.toml')


def _committed_comparisons():
  """The committed exports with comparisons (results/**/comparisons.csv's folders)."""
  return sorted(p.parent for p in ROOT.glob('results/**/comparisons.csv'))


@pytest.mark.parametrize('export', _committed_comparisons(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_committed_comparison_is_its_study_files_interval_for_its_looks(export):
  """Each interval of an export's comparisons.csv is the one the study file it ran (provenance.json) gives its
  results.csv, corrected for its looks (the study file's and looks.json)."""
  study = study_looks.with_recorded(reuse.exported_study(str(export)), str(export))
  with open(export / 'results.csv', newline='') as f:
    rows = list(csv.DictReader(f))
  found = {(c.metric, c.a, c.b): c for m in study.plot.metrics for c in study_stats.compare(study, rows, m)}
  with open(export / 'comparisons.csv', newline='') as f:
    for row in csv.DictReader(f):
      comparison = found[(row['metric'], row['a'], row['b'])]
      assert row['verdict'] == comparison.verdict and row['ci_low'] == ('' if comparison.low is None else
                                                                         str(comparison.low)), row


def test_the_cup_depth_prior_study_added_seeds_after_looking_and_says_so():
  export = ROOT / 'results' / 'studies' / 'depth_prior_cup'
  assert study_stats.looks(study_looks.with_recorded(reuse.exported_study(str(export)), str(export))) == (3, 5)
  with open(export / 'comparisons.csv', newline='') as f:
    psnr = next(r for r in csv.DictReader(f) if r['metric'] == 'psnr')
  assert psnr['verdict'] == 'UNDECIDED: the 97.5% interval contains 0'
