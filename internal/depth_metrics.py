"""Depth error against exact depths: mean absolute error and the fraction within 1% / 5% of the depth range.

Depths here are the ray parameter t along the loaders' (unnormalized) ray directions, whose camera-frame |z| is
1: that is the camera z-depth, the generated scene's stored depth and, for non-NDC rays, the rendered
distance_mean. NDC renderings (LLFF layout) are converted back to that world t first.
"""

from typing import Dict, Optional

import numpy as np

DEPTH_METRICS = ('depth_mae', 'depth_within_1pct', 'depth_within_5pct')


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
    distance = np.reshape(distance, gt[i].shape)
    if ndc:
      rays = test_set.rays
      distance = ndc_distance_to_depth(distance, rays.origins[i].astype(np.float64),
                                       rays.directions[i].astype(np.float64),
                                       np.asarray(test_set.camtoworlds[i], np.float64)[:3, 3],
                                       rays.viewdirs[i].astype(np.float64))
    return depth_errors(distance, gt[i], valid[i], depth_range)
  return score
