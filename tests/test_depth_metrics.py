"""Depth metrics: hand-computed errors, the generated scene's depths in ray units, NDC back to world depth."""

import json

import numpy as np
import pytest

from internal import datasets
from internal import depth_metrics
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
