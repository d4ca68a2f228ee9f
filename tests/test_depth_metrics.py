"""Depth metrics: hand-computed errors, the generated scene's depths in ray units, NDC back to world depth."""

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest

from internal import datasets
from internal.evaluation import depth_metrics
from internal.evaluation import evaluate
from internal.pipeline import loop
from test_checkpoints import tiny_config


def test_depth_errors_by_hand():
  gt = np.array([[2., 3.], [4., 0.]])
  pred = np.array([[2.03, 3.1], [3.5, 9.]])
  values = depth_metrics.depth_errors(pred, gt, gt > 0, depth_range=4.)  # 1% = 0.04, 5% = 0.2.
  assert values['depth_mae'] == pytest.approx((0.03 + 0.1 + 0.5) / 3)
  assert values['depth_within_1pct'] == pytest.approx(1 / 3) and values['depth_within_5pct'] == pytest.approx(2 / 3)
  assert depth_metrics.depth_errors(pred, gt, np.zeros((2, 2), bool), 4.) == dict.fromkeys(depth_metrics.DEPTH_METRICS)


def _surface_residual(solid, p):
  """[R] distance-like residual of points p [R,3] to a solid's surface (0 on it)."""
  if solid['shape'] == 'sphere':
    return np.linalg.norm(p - solid['centre'], axis=-1) - solid['radius']
  if solid['shape'] == 'plane':
    return p @ np.array(solid['normal']) - solid['offset']
  local = (p - solid['centre']) @ np.array(solid['rotation'])
  return np.max(np.abs(local) - solid['half'], axis=-1)


def test_generated_object_depth_is_the_ray_parameter(tmp_path):
  scene = tmp_path / 'object'
  test_set = datasets.load_dataset('test', tiny_config(scene, tmp_path / 'run', 'Config.generated_size = (12, 16)'),
                                   ground_truth=True)
  solids = json.loads((scene / 'scene.json').read_text())['solids']
  hit = test_set.depths > 0
  assert hit.mean() > .3
  points = (test_set.rays.origins + test_set.depths[..., None] * test_set.rays.directions)[hit].astype(np.float64)
  residual = np.min(np.abs(np.stack([_surface_residual(s, points) for s in solids])), axis=0)
  assert residual.max() < 1e-4  # Every depth puts o + t d on a solid: the rendered t's units.


def test_ndc_distance_maps_back_to_the_forward_rig_depth(tmp_path):
  config = tiny_config(tmp_path / 'forward', tmp_path / 'run', "Config.generated_rig = 'forward'",
                       'Config.generated_size = (12, 16)')
  test_set = datasets.load_dataset('test', config, ground_truth=True)
  i = 1
  rays = test_set.rays
  o_w = test_set.camtoworlds[i][:3, 3].astype(np.float64)
  d_w = rays.viewdirs[i].astype(np.float64)
  gt = test_set.depths[i].astype(np.float64)
  z = o_w[2] + gt * d_w[..., 2]                       # World z of the true surface point.
  t_ndc = ((1. + 2. / z) - rays.origins[i][..., 2]) / rays.directions[i][..., 2]  # Its NDC ray parameter.
  assert np.all((t_ndc > 0.) & (t_ndc < 1.))
  p_w = o_w + gt[..., None] * d_w                     # The NDC ray at t_ndc is the world point's projection.
  focal, (h, w) = 1. / test_set.pixtocams[i][0, 0], gt.shape
  p_ndc = rays.origins[i] + t_ndc[..., None] * rays.directions[i]
  np.testing.assert_allclose(p_ndc[..., 0], -2. * focal / w * p_w[..., 0] / p_w[..., 2], atol=1e-4)
  np.testing.assert_allclose(p_ndc[..., 1], -2. * focal / h * p_w[..., 1] / p_w[..., 2], atol=1e-4)
  back = depth_metrics.ndc_distance_to_depth(t_ndc, rays.origins[i].astype(np.float64),
                                             rays.directions[i].astype(np.float64), o_w, d_w)
  np.testing.assert_allclose(back, gt, rtol=1e-4)
  score = depth_metrics.scorer(test_set, ndc=True)
  assert score(i, t_ndc)['depth_within_1pct'] == 1.
  assert score(i, t_ndc * 0.)['depth_within_5pct'] < 1.


def _reference(run_dir, step, depths, accs):
  """Writes depth_<id>.npz files (ids 0, 1, ...) of a fake evaluation at step into run_dir."""
  out = run_dir / f'test_preds_step_{step}'
  out.mkdir(parents=True)
  for view_id, (distance, acc) in enumerate(zip(depths, accs)):
    np.savez(depth_metrics.depth_file(str(out), view_id), distance=distance, acc=acc)


def test_pseudo_depth_against_the_newest_reference_by_hand(tmp_path):
  test_set = SimpleNamespace(ids=[0, 1], images=np.zeros((2, 1, 2, 3)))
  _reference(tmp_path, 5, [np.full((1, 2), 9.)] * 2, [np.ones((1, 2))] * 2)   # Older: must not be used.
  _reference(tmp_path, 10, [np.array([[2., 3.]]), np.array([[6., 4.]])], [np.array([[1., .2]]), np.ones((1, 2))])
  score = depth_metrics.reference_scorer(test_set, False, str(tmp_path), positions=[0, 1])
  # Opaque reference depths 2, 6, 4: range 4, so 1% = 0.04 and 5% = 0.2; view 0's second pixel is not opaque.
  assert score(0, np.array([[2.1, 0.]])) == pytest.approx(
      {'pseudo_depth_mae': .1, 'pseudo_depth_within_1pct': 0., 'pseudo_depth_within_5pct': 1.})
  assert score(1, np.array([[6.03, 5.]])) == pytest.approx(
      {'pseudo_depth_mae': (.03 + 1.) / 2, 'pseudo_depth_within_1pct': .5, 'pseudo_depth_within_5pct': .5})


def test_pseudo_depth_reference_errors_name_the_problem(tmp_path):
  test_set = SimpleNamespace(ids=[0, 3], images=np.zeros((2, 1, 2, 3)))
  with pytest.raises(ValueError, match='holds no evaluation with depths'):
    depth_metrics.reference_scorer(test_set, False, str(tmp_path), positions=[0])
  _reference(tmp_path, 7, [np.ones((1, 2))], [np.ones((1, 2))])
  with pytest.raises(ValueError, match=r'depth_003\.npz.*same test views'):
    depth_metrics.reference_scorer(test_set, False, str(tmp_path), positions=[1])
  test_set.images = np.zeros((2, 4, 4, 3))
  with pytest.raises(ValueError, match=r'\(1, 2\) depth map.*\(4, 4\)'):
    depth_metrics.reference_scorer(test_set, False, str(tmp_path), positions=[0])


def test_a_run_against_its_own_depths_has_zero_pseudo_error(tmp_path, scene_dir):
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 2', 'Config.compute_lpips = False',
                       'Config.eval_test_ids = [0, 1]')
  loop.train(config)
  evaluate.evaluate(config)
  again = dataclasses.replace(config, depth_reference_dir=str(tmp_path / 'run'), overwrite=True)
  means = evaluate.evaluate(again)['means']
  assert means['pseudo_depth_mae'] == 0. and means['pseudo_depth_within_1pct'] == 1.
