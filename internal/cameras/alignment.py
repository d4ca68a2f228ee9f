"""The one similarity that best maps a set of cameras onto another, the camera errors with and without it, the
camera distance (the unit of translations) and the rotation angle.

Cameras known only up to a similarity (structure-from-motion, refinement: any rotation, translation and scale of
every camera and the scene together changes no image) are compared after aligning them, as BARF evaluates: the
similarity x -> s Q x + t minimizes, over the cameras, the squared distances of the centres (scaled by their spread)
plus the squared differences of the rotation matrices, one Procrustes problem (Umeyama's, with the orientations
added), so that it is defined for any number of cameras (one: its rotation and centre; scale 1). A similarity also
explains part of any error (cameras each turned by exactly 5 degrees about random axes read less than 5 after it,
the fewer the cameras the less: tests/test_pose_correction.py measures it), so an error is compared only with one
measured under the same alignment; where both sets share their frame (the reference's: noise and refinement
without a capture's separate model) errors without the similarity are reported too.
"""

from typing import NamedTuple, Optional

import numpy as np
from scipy.spatial import transform as spatial_transform

from internal.cameras import algebra
from internal.cameras.records import RaySpace

NDC_DISTANCE = 2.  # The world depth whose NDC z is 0: half-way through NDC's disparity range [1, 0].



class Similarity(NamedTuple):
  """x -> scale * rotation @ x + shift."""
  scale: float
  rotation: np.ndarray  # [3,3]
  shift: np.ndarray     # [3]

  def cameras(self, camtoworlds: np.ndarray) -> np.ndarray:
    """[N,3,4] cameras c2w [N,3,4] carried by the similarity (rotations turned, centres mapped)."""
    c2w = np.asarray(camtoworlds, np.float64)
    centres = self.scale * c2w[:, :, 3] @ self.rotation.T + self.shift
    return np.concatenate([self.rotation @ c2w[:, :, :3], centres[..., None]], -1)


def fit(source: np.ndarray, target: np.ndarray) -> Similarity:
  """The Similarity taking cameras source [N,3,4] closest to target [N,3,4] (module docstring)."""
  source, target = np.asarray(source, np.float64), np.asarray(target, np.float64)
  src_c, tgt_c = source[:, :, 3], target[:, :, 3]
  src_mean, tgt_mean = src_c.mean(0), tgt_c.mean(0)
  src_off, tgt_off = src_c - src_mean, tgt_c - tgt_mean
  spread = np.sqrt(np.mean(np.sum(src_off**2, -1)))
  unit = 1. / spread if spread > 0 else 0.
  # Correlation of the target's axes with the source's: centre offsets (in units of the spread) and rotations.
  correlation = unit**2 * tgt_off.T @ src_off + np.einsum('nij,nkj->ik', target[:, :, :3], source[:, :, :3])
  u, _, vt = np.linalg.svd(correlation)
  fix = np.diag([1., 1., np.sign(np.linalg.det(u @ vt))])
  rotation = u @ fix @ vt
  turned = src_off @ rotation.T
  scale = float(np.sum(turned * tgt_off) / np.sum(src_off**2)) if spread > 0 else 1.
  return Similarity(scale, rotation, tgt_mean - scale * rotation @ src_mean)


def rotation_angle(rotation: np.ndarray) -> np.ndarray:
  """Angles [...] (radians) of rotations [...,3,3], from their trace (float64)."""
  trace = np.trace(np.asarray(rotation, np.float64), axis1=-2, axis2=-1)
  return np.arccos(np.clip((trace - 1.) / 2., -1., 1.))


def own_axes_turns(cameras: np.ndarray, reference: np.ndarray) -> np.ndarray:
  """[N,3] rotation vectors (degrees) that turn each reference camera [N,3,4] into its counterpart in cameras
  [N,3,4] (the same frame: align them first), in the reference camera's own axes (x right, y up, z along its axis):
  a turn that every view shares there (a common tilt) is their mean."""
  turns = np.swapaxes(np.asarray(reference, np.float64)[:, :, :3], 1, 2) @ np.asarray(cameras, np.float64)[:, :, :3]
  return np.rad2deg(spatial_transform.Rotation.from_matrix(turns).as_rotvec())


def camera_distance(camtoworlds: np.ndarray, space: Optional[RaySpace] = None) -> float:
  """The distance of cameras [N,3,4] from the middle of the scene they see, the unit of translations (camera noise,
  camera errors): for NDC rays NDC_DISTANCE (LLFF's frame puts the nearest scene depth at 1 / 0.75); for world rays
  the middle of their depth range, (near + far) / 2 (4 for the generated object rig and Blender, whose cameras sit
  4 from the object's centre); for cameras without rays (space None: structure-from-motion against a reference)
  the median distance from the point nearest to every optical axis."""
  if space is None:
    c2w = np.asarray(camtoworlds, np.float64)
    return float(np.median(np.linalg.norm(c2w[:, :, 3] - algebra.focus_point(c2w), axis=-1)))
  return NDC_DISTANCE if space.ndc_focal else .5 * (space.near + space.far)


def errors(cameras: np.ndarray, reference: np.ndarray, distance: float, align: bool = True) -> dict:
  """{'rotation_deg' [N], 'translation' [N]} of cameras [N,3,4] against reference [N,3,4]: rotation angles in
  degrees, centre distances as a fraction of distance (the reference's camera_distance); after the similarity
  taking cameras onto reference, or (align False) as they are, for sets in the same frame."""
  aligned = fit(cameras, reference).cameras(cameras) if align else np.asarray(cameras, np.float64)
  reference = np.asarray(reference, np.float64)
  angles = rotation_angle(np.swapaxes(aligned[:, :, :3], 1, 2) @ reference[:, :, :3])
  gaps = np.linalg.norm(aligned[:, :, 3] - reference[:, :, 3], axis=-1)
  return {'rotation_deg': np.rad2deg(angles), 'translation': gaps / distance}


def summary(values: dict) -> dict:
  """{'<name>_median', '<name>_mean', '<name>_max'} of errors' arrays, as floats."""
  return {f'{name}_{stat}': float(fn(v)) for name, v in values.items()
          for stat, fn in (('median', np.median), ('mean', np.mean), ('max', np.max))}
