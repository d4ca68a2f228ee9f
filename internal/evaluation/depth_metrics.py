"""Depth error against exact depths: mean absolute error and the fraction within 1% / 5% of the depth range.

Against a pseudo ground truth (the depths another run rendered for the same test views, as in the paper's
appendix: mip-NeRF trained on many views) the same errors are reported as pseudo_depth_*, over the pixels that
run rendered opaque. On a capture, against its structure-from-motion points where each test view observed them,
as sfm_depth_* (a sparse reference, in the capture's units: its median camera is 1 from the centre).

Depths here are the ray parameter t along the loaders' (unnormalized) ray directions, whose camera-frame |z| is
1: that is the camera z-depth, the generated scene's stored depth and, for non-NDC rays, the rendered
distance_mean. NDC renderings (LLFF layout) are converted back to that world t first.
"""

import glob
import os
import re
from typing import Dict, Optional

import numpy as np

from internal.datasets import sfm_depth
from internal.evaluation import metric_registry

DEPTH_METRICS = metric_registry.names(metric_registry.DEPTH)
REFERENCE_OPACITY = .5   # Reference pixels at least this opaque hold a surface to compare with.


def depth_file(eval_dir: str, view_id: int) -> str:
  """<eval_dir>/depth_<view_id>.npz: a test view's rendered distance and opacity [H,W], written by eval."""
  return os.path.join(eval_dir, f'depth_{view_id:03d}.npz')


def depth_errors(pred, gt, valid, depth_range: float) -> Dict[str, Optional[float]]:
  """DEPTH_METRICS of pred [H,W] vs gt [H,W] over the valid [H,W] pixels; tolerances are % of depth_range."""
  valid = np.asarray(valid, bool)
  if not valid.any():
    return dict.fromkeys(DEPTH_METRICS)
  error = np.abs(np.asarray(pred, np.float64) - np.asarray(gt, np.float64))[valid]
  return {'depth_mae': float(error.mean()), 'depth_within_1pct': float(np.mean(error <= .01 * depth_range)),
          'depth_within_5pct': float(np.mean(error <= .05 * depth_range))}


def ndc_distance_to_depth(distance, ndc_origins, ndc_directions, world_origin, world_directions,
                          near: float = 1.) -> np.ndarray:
  """World t [H,W] of NDC distances [H,W] along NDC rays [H,W,3] whose world rays start at world_origin [3].

  NDC z = 1 + 2 near / z maps the point back to world z; t follows from the world ray's z component.
  """
  z_ndc = ndc_origins[..., 2] + np.asarray(distance, np.float64) * ndc_directions[..., 2]
  with np.errstate(divide='ignore'):
    z_world = 2. * near / (z_ndc - 1.)
  return (z_world - world_origin[2]) / world_directions[..., 2]


def world_depth(test_set, i: int, distance, ndc: bool) -> np.ndarray:
  """World t [H,W] of the rendered distance [H,W] of test position i (converted back from NDC when ndc)."""
  distance = np.reshape(np.asarray(distance, np.float64), test_set.images[i].shape[:2])
  if not ndc:
    return distance
  rays = test_set.rays
  return ndc_distance_to_depth(distance, rays.origins[i].astype(np.float64), rays.directions[i].astype(np.float64),
                               np.asarray(test_set.camtoworlds[i], np.float64)[:3, 3],
                               rays.viewdirs[i].astype(np.float64))


def newest_eval_dir(run_dir: str) -> str:
  """The newest test_preds_step_<step> folder of run_dir holding depth files; ValueError naming the folder."""
  found = [d for d in glob.glob(os.path.join(run_dir, 'test_preds_step_*'))
           if glob.glob(os.path.join(d, 'depth_*.npz'))]
  if not found:
    raise ValueError(f'Config.depth_reference_dir = {run_dir!r} holds no evaluation with depths '
                     '(test_preds_step_<step>/depth_<id>.npz); evaluate that run first')
  return max(found, key=lambda d: int(re.search(r'(\d+)$', d).group(1)))


def reference_scorer(test_set, ndc: bool, reference_dir: str, positions):
  """(position, rendered distance [H,W]) -> pseudo_depth_* against reference_dir's depths of those views.

  The tolerance range is that of the reference's opaque depths over the given test positions.
  """
  eval_dir = newest_eval_dir(reference_dir)
  refs = {}
  for i in positions:
    path = depth_file(eval_dir, int(test_set.ids[i]))
    if not os.path.isfile(path):
      raise ValueError(f'{path!r} is missing: the reference run must be evaluated on the same test views')
    with np.load(path) as f:
      distance, acc = f['distance'], f['acc']
    if distance.shape != test_set.images[i].shape[:2]:
      raise ValueError(f'{path!r} holds a {distance.shape} depth map; this evaluation renders '
                       f'{test_set.images[i].shape[:2]}: evaluate both at the same resolution')
    refs[i] = world_depth(test_set, i, distance, ndc), acc >= REFERENCE_OPACITY
  valid = np.concatenate([d[v] for d, v in refs.values()])
  depth_range = float(valid.max() - valid.min()) if valid.size else 0.

  def score(i: int, distance):
    errors = depth_errors(world_depth(test_set, i, distance, ndc), refs[i][0], refs[i][1], depth_range)
    return {metric_registry.PSEUDO_PREFIX + k: v for k, v in errors.items()}
  return score


def scorer(test_set, ndc: bool):
  """(position, rendered distance [H,W]) -> DEPTH_METRICS of that test view; None without exact depths.

  The depth range is that of the valid (hit, > 0) exact depths over the whole test split.
  """
  if test_set.depths is None:
    return None
  gt = np.asarray(test_set.depths, np.float64)
  valid = gt > 0.
  if not valid.any():
    return None
  depth_range = float(gt[valid].max() - gt[valid].min())

  def score(i: int, distance):
    return depth_errors(world_depth(test_set, i, distance, ndc), gt[i], valid[i], depth_range)
  return score


def sfm_scorer(test_set, ndc: bool, config):
  """(position, rendered distance [H,W]) -> sfm_depth_* at the capture's own points each test view observed
  (internal/datasets/sfm_depth.evaluation_depths); the tolerance range is that of their depths over the views."""
  points = sfm_depth.evaluation_depths(test_set, config)
  valid = points > 0
  depth_range = float(points[valid].max() - points[valid].min()) if valid.any() else 0.

  def score(i: int, distance):
    errors = depth_errors(world_depth(test_set, i, distance, ndc), points[i], valid[i], depth_range)
    return {metric_registry.SFM_PREFIX + k: v for k, v in errors.items()}
  return score
