"""tools.camera_report: the share of the noise cost a method recovers, from a study's results; bad input."""

import csv

import numpy as np
import pytest

from internal.datasets import pose_correction

from tools import camera_report


def _write(path, rows):
  with open(path, 'w', newline='') as f:
    writer = csv.DictWriter(f, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)


def _row(method, noise, seed, psnr, rotation=''):
  return {'method': method, 'noise': noise, 'seed': seed, 'status': 'done', 'psnr': psnr,
          'camera_rotation_deg': rotation, 'camera_translation': rotation and .01}


def test_the_share_of_the_noise_cost_recovered_per_seed(tmp_path):
  rows = [_row('freenerf', 'exact', 0, 20.), _row('freenerf', '5deg', 0, 16., 4.5), _row('refine', '5deg', 0, 19., .8),
          _row('freenerf', 'exact', 1, 21.), _row('freenerf', '5deg', 1, 19., 4.4), _row('refine', '5deg', 1, 18., .9),
          {**_row('refine', '5deg', 2, 30.), 'status': 'missing'}]
  _write(tmp_path / 'results.csv', rows)
  found = camera_report.targets(camera_report._rows(tmp_path / 'results.csv'), 'noise', 'exact', '5deg', 'freenerf')
  assert [(m, s, share) for m, s, _, _, _, share, *_ in found] == [('freenerf', 0, 0.), ('freenerf', 1, 0.),
                                                              ('refine', 0, .75), ('refine', 1, -.5)]
  assert camera_report.main(['--out', str(tmp_path / 'out'), '--study', str(tmp_path / 'results.csv')]) == 0
  text = (tmp_path / 'out' / 'targets.md').read_text()
  assert '| refine | 0.850 | 0.010 | 18.500 | 0.125 | nan | nan |' in text and '"command"' in text


def test_the_errors_without_a_similarity_come_from_the_runs_that_have_them(tmp_path):
  rows = [{**_row('refine', '5deg', 0, 19., .8), 'cell': 'refine_0'},
          {**_row('refine', '5deg', 1, 18., .9), 'cell': 'b'}, {**_row('freenerf', 'exact', 0, 20.), 'cell': 'c'}]
  found = camera_report.targets(rows, 'noise', 'exact', '5deg', 'freenerf',
                                {'refine_0': {'rotation_deg': 2.5, 'common_turn_deg': 2.25}})
  assert [f[-2:] for f in found][0] == (2.5, 2.25) and np.isnan(found[1][-1])
  assert camera_report.study_unaligned(str(tmp_path / 'results.csv'), rows, 'noise', '5deg') == {}  # No runs here.


def test_turns_are_the_rotation_vectors_between_cameras():
  rng = np.random.default_rng(3)
  vectors, base = .1 * rng.normal(size=(4, 3)), pose_correction.so3_exp(rng.normal(size=(4, 3)))
  reference = np.concatenate([base, rng.normal(size=(4, 3, 1))], -1)
  turned = np.concatenate([pose_correction.so3_exp(vectors) @ base, reference[:, :, 3:]], -1)
  np.testing.assert_allclose(camera_report.turns(turned, reference), vectors, atol=1e-12)


@pytest.mark.parametrize('args, message', [
    (['--study', 'nowhere.csv'], "--study 'nowhere.csv' does not exist"),
    (['--runs', 'nowhere'], "is not a run that refined its cameras")])
def test_bad_input_is_one_line(tmp_path, args, message, capsys):
  from internal import cli
  assert cli.run(lambda: camera_report.main(['--out', str(tmp_path), *args])) == 2
  assert message in capsys.readouterr().err
