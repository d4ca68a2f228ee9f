"""Recovered cameras against independent ones, after a similarity alignment (structure-from-motion fixes neither
scale, rotation nor position of its frame): per camera the rotation error in degrees and the position error as a
fraction of the camera distance (the reference cameras' median distance from the point nearest to all their optical
axes). The alignment's rotation is the mean of the cameras' rotation differences, its scale and translation the
least-squares fit of the centres under it: camera centres along an arc alone leave the rotation about the arc's
chord poorly determined (on the cup, a fit of the centres alone tilts every camera by 2 degrees).

Cameras are camera-to-world [N, 3, 4] in OpenCV axes (x right, y down, z forward), as the capture loader keeps them.
"""

from typing import Dict, Optional, Tuple

import numpy as np

from internal.cameras import algebra
from internal.datasets import colmap_model

# LLFF's poses_bounds.npy columns are (down, right, backward); OpenCV's (right, down, forward).
LLFF_TO_OPENCV = np.array([[0., 1., 0.], [1., 0., 0.], [0., 0., -1.]])


def llff_cameras(poses_bounds: np.ndarray) -> np.ndarray:
  """Camera-to-world [N, 3, 4] (OpenCV axes) of LLFF's poses_bounds rows [N, 17]."""
  poses = poses_bounds[:, :15].reshape(-1, 3, 5)
  return np.concatenate([poses[:, :, :3] @ LLFF_TO_OPENCV, poses[:, :, 3:4]], -1)


def similarity(source: np.ndarray, target: np.ndarray) -> Tuple[float, np.ndarray, np.ndarray]:
  """(s, R [3, 3], t [3]) minimizing sum |s R source_i + t - target_i|^2 over points [N, 3] (Umeyama, 1991)."""
  mean_s, mean_t = source.mean(0), target.mean(0)
  xs, xt = source - mean_s, target - mean_t
  u, d, vt = np.linalg.svd(xt.T @ xs / len(source))
  sign = np.diag([1., 1., np.sign(np.linalg.det(u @ vt)) or 1.])
  rotation = u @ sign @ vt
  scale = float(np.trace(np.diag(d) @ sign) / (xs ** 2).sum(1).mean())
  return scale, rotation, mean_t - scale * rotation @ mean_s


def transform(c2w: np.ndarray, fit: Tuple[float, np.ndarray, np.ndarray]) -> np.ndarray:
  """Cameras [N, 3, 4] moved by the similarity fit (s, R, t): rotations R @ R_i, centres s R c_i + t."""
  scale, rotation, translation = fit
  return np.concatenate([rotation @ c2w[:, :, :3], (scale * c2w[:, :, 3] @ rotation.T + translation)[..., None]], -1)


def camera_distance(c2w: np.ndarray) -> float:
  """The median distance of the cameras [N, 3, 4] from the point nearest to their optical axes."""
  return float(np.median(np.linalg.norm(c2w[:, :, 3] - algebra.focus_point(c2w), axis=-1)))


def rotation_degrees(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  """[N] angles in degrees of the rotations taking a [N, 3, 3] to b [N, 3, 3]."""
  cos = (np.trace(np.transpose(a, (0, 2, 1)) @ b, axis1=1, axis2=2) - 1.) / 2.
  return np.degrees(np.arccos(np.clip(cos, -1., 1.)))


def mean_rotation(rotations: np.ndarray) -> np.ndarray:
  """[3, 3] the rotation nearest (Frobenius) to the mean of rotations [N, 3, 3] (their chordal mean)."""
  u, _, vt = np.linalg.svd(rotations.mean(0))
  return u @ np.diag([1., 1., np.sign(np.linalg.det(u @ vt)) or 1.]) @ vt


def alignment(c2w: np.ndarray, reference: np.ndarray) -> Tuple[float, np.ndarray, np.ndarray]:
  """(s, R, t) taking cameras c2w [N, 3, 4] onto reference [N, 3, 4]: R the mean rotation difference, s and t the
  least-squares fit of the centres under R."""
  rotation = mean_rotation(reference[:, :, :3] @ np.transpose(c2w[:, :, :3], (0, 2, 1)))
  source, target = c2w[:, :, 3] @ rotation.T, reference[:, :, 3]
  xs, xt = source - source.mean(0), target - target.mean(0)
  scale = float((xs * xt).sum() / (xs ** 2).sum())
  return scale, rotation, target.mean(0) - scale * source.mean(0)


def pose_errors(c2w: np.ndarray, reference: np.ndarray, distance: Optional[float] = None) -> Dict[str, np.ndarray]:
  """{'rotation_deg' [N], 'position' [N] (fraction of distance, default the reference's camera distance)} of
  cameras c2w [N, 3, 4] after their alignment to reference [N, 3, 4] (the same cameras, same order)."""
  aligned = transform(c2w, alignment(c2w, reference))
  distance = camera_distance(reference) if distance is None else distance
  position = np.linalg.norm(aligned[:, :, 3] - reference[:, :, 3], axis=-1) / distance
  return {'rotation_deg': rotation_degrees(aligned[:, :, :3], reference[:, :, :3]), 'position': position}


def model_cameras(model) -> Tuple[list, np.ndarray]:
  """(image names in name order, their camera-to-world [N, 3, 4] in OpenCV axes) of a colmap_model.Model."""
  images = sorted(model.images.values(), key=lambda i: i.name)
  rotations = np.stack([colmap_model.qvec_to_rotmat(i.qvec).T for i in images])
  centres = np.stack([colmap_model.camera_center(i) for i in images])
  return [i.name for i in images], np.concatenate([rotations, centres[..., None]], -1)
