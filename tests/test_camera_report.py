"""lab.camera_report: the share of the noise cost a method recovers, from a study's results; bad input."""

import csv

import numpy as np
import pytest
from scipy.spatial import transform as spatial_transform

from internal import cli
from internal import runs
from lab import camera_report


def _write(path, rows):
  with open(path, 'w', newline='') as f:
    writer = csv.DictWriter(f, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)


def _row(method, noise, seed, psnr, rotation='', posed=''):
  return {'method': method, 'noise': noise, 'seed': seed, 'status': 'done', 'psnr': psnr, 'psnr@test_pose': posed,
          'camera_rotation_deg': rotation, 'camera_translation': rotation and .01,
          'camera_rotation_deg_unaligned': rotation and rotation + 1., 'camera_translation_unaligned': rotation and .02}


def test_the_share_of_the_noise_cost_recovered_per_seed(tmp_path):
  rows = [_row('freenerf', 'exact', 0, 20.), _row('freenerf', '5deg', 0, 16., 4.5), _row('refine', '5deg', 0, 19., .8),
          _row('freenerf', 'exact', 1, 21.), _row('freenerf', '5deg', 1, 19., 4.4), _row('refine', '5deg', 1, 18., .9),
          {**_row('refine', '5deg', 2, 30.), 'status': 'missing'}]
  _write(tmp_path / 'results.csv', rows)
  found = camera_report.targets(camera_report._rows(tmp_path / 'results.csv'), 'noise', 'exact', '5deg', 'freenerf')
  assert [(m, s, share) for m, s, _, _, _, share, _ in found] == [('freenerf', 0, 0.), ('freenerf', 1, 0.),
                                                                 ('refine', 0, .75), ('refine', 1, -.5)]
  assert camera_report.main(['--out', str(tmp_path / 'out'), '--study', str(tmp_path / 'results.csv')]) == 0
  text = (tmp_path / 'out' / 'targets.md').read_text()
  assert '| refine | 0.850 | 0.010 | 18.500 | 0.125 |  |' in text and '"command"' in text  # No drift: blank.
  assert 'after the similarity' in text and '| refine | 1.850 | 0.0200 |' in text  # The target's alignment said.


def test_the_share_under_another_psnr_column_and_the_drift_on_the_clean_cameras(tmp_path):
  rows = [_row('freenerf', 'exact', 0, 20., posed=22.), _row('freenerf', '5deg', 0, 16., 4.5, 18.),
          _row('refine', 'exact', 0, 19., .25, 21.5), _row('refine', '5deg', 0, 17., .8, 21.)]
  _write(tmp_path / 'results.csv', rows)
  found = camera_report.targets(camera_report._rows(tmp_path / 'results.csv'), 'noise', 'exact', '5deg', 'freenerf',
                                'psnr@test_pose')
  assert found[1] == ('refine', 0, .8, .01, 21., .75, .25)
  assert camera_report.main(['--out', str(tmp_path / 'out'), '--study', str(tmp_path / 'results.csv'),
                             '--psnr', 'psnr@test_pose']) == 0
  assert not (tmp_path / 'out' / 'targets.md').exists()
  text = (tmp_path / 'out' / 'targets_psnr@test_pose.md').read_text()
  assert '| refine | 0 | 0.800 | 0.0100 | 21.000 | 0.75 | 0.250 |' in text and 'in PSNR (`psnr@test_pose`)' in text
  assert camera_report.main(['--out', str(tmp_path / 'out'), '--study', str(tmp_path / 'results.csv'),
                             '--methods', 'freenerf', '--name', 'baseline.md']) == 0
  assert '| refine |' not in (tmp_path / 'out' / 'baseline.md').read_text()


@pytest.mark.parametrize('args, message', [
    (['--study', 'nowhere.csv'], "--study 'nowhere.csv' does not exist"),
    (['--runs', 'nowhere'], "is not a run that refined its cameras")])
def test_bad_input_is_one_line(tmp_path, args, message, capsys):
  assert cli.run(lambda: camera_report.main(['--out', str(tmp_path), *args])) == 2
  assert message in capsys.readouterr().err


@pytest.mark.parametrize('rows, args, message', [
    ([{'method': 'freenerf', 'seed': 0, 'status': 'done', 'psnr': 20.}], [],
     "--axis 'noise': --study '{study}' has no such column; expected the study axis of the camera noise"),
    ([_row('freenerf', 'exact', 0, 20.), _row('freenerf', '5deg', 0, 16.)], ['--noisy', '7deg'],
     "--noisy '7deg': no finished row of --study '{study}' has it; expected one of ['5deg', 'exact']"),
    ([_row('freenerf', 'exact', 0, 20.), _row('freenerf', '5deg', 0, 16.)], ['--clean', 'none'],
     "--clean 'none': no finished row"),
    ([_row('freenerf', 'exact', 0, 20.), _row('freenerf', '5deg', 0, 16.)], ['--baseline', 'nerf'],
     "--baseline 'nerf': no finished row of --study '{study}' has it; expected one of ['freenerf']"),
    ([{**_row('freenerf', 'exact', 0, 20.), 'status': 'missing'}], [], "--study '{study}': no finished row"),
    ([_row('freenerf', 'exact', 0, 20.), _row('freenerf', '5deg', 0, 16.)], ['--methods', 'refine'],
     "--methods ['refine']: no finished row of --study '{study}' has them"),
    ([_row('freenerf', 'exact', 0, 20.), _row('freenerf', '5deg', 0, 16.)], ['--psnr', 'psnr@other'],
     "--study '{study}' has no column 'psnr@other'; expected a study with seeds whose results give method, seed and "
     "psnr@other (--psnr)"),
])
def test_a_study_without_the_noise_axis_or_the_labels_asked_is_one_line(tmp_path, capsys, rows, args, message):
  _write(tmp_path / 'results.csv', rows)
  study = str(tmp_path / 'results.csv')
  assert cli.run(lambda: camera_report.main(['--out', str(tmp_path / 'out'), '--study', study, *args])) == 2
  err = capsys.readouterr().err
  assert err.startswith('error: ' + message.format(study=study)) and len(err.strip().splitlines()) == 1, err
  assert not (tmp_path / 'out').exists()


def test_two_runs_of_one_name_are_one_line_before_any_picture(tmp_path, capsys):
  first, second = tmp_path / 'a' / 'freenerf__cup' / 'run', tmp_path / 'b' / 'freenerf__cup' / 'run'
  assert cli.run(lambda: camera_report.main(['--out', str(tmp_path / 'out'), '--runs', str(first),
                                             str(second)])) == 2
  err = capsys.readouterr().err
  assert err == (f"error: --runs {str(first)!r} and {str(second)!r} are both named 'freenerf__cup' (a study cell's "
                 "folder, or the run's): both pictures would be cameras_freenerf__cup.png; give them in separate "
                 'commands with another --out\n')
  assert not (tmp_path / 'out').exists()


def test_errors_in_each_camera_s_own_axes_and_the_turn_the_views_share():
  rng = np.random.default_rng(0)
  reference = np.concatenate([spatial_transform.Rotation.random(4, random_state=1).as_matrix(),
                              rng.normal(size=(4, 3, 1))], -1)
  own = np.array([[.3, 0., 0.], [.3, .2, 0.], [.3, -.2, 0.], [.3, 0., .4]])  # A tilt of .3 shared, and more.
  turned = reference.copy()
  turned[:, :, :3] = reference[:, :, :3] @ spatial_transform.Rotation.from_rotvec(np.deg2rad(own)).as_matrix()
  np.testing.assert_allclose(runs.own_axes_turns(turned, reference), own, atol=1e-9)
  row = camera_report.modes_row('r', {'reference': reference, 'refined': turned}, 'refined')
  assert row == '| r | refined | +0.300 | +0.000 | +0.100 | 0.316 | 0.361 | 0.224 |'
