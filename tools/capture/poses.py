"""Recovered cameras against independent ones, after the similarity alignment of internal/cameras/alignment.py
(structure-from-motion fixes neither scale, rotation nor position of its frame; the one fit of the centres and the
orientations together, since camera centres along an arc alone leave the rotation about the arc's chord poorly
determined): per camera the rotation error in degrees and the position error as a fraction of the camera distance
(the reference cameras' median distance from the point nearest to all their optical axes).

Cameras are camera-to-world [N, 3, 4] in OpenCV axes (x right, y down, z forward), as the capture loader keeps them.
"""

from typing import Dict, Optional, Tuple

import numpy as np

from internal.cameras import alignment
from internal.datasets import colmap_model

# LLFF's poses_bounds.npy columns are (down, right, backward); OpenCV's (right, down, forward).
LLFF_TO_OPENCV = np.array([[0., 1., 0.], [1., 0., 0.], [0., 0., -1.]])


def llff_cameras(poses_bounds: np.ndarray) -> np.ndarray:
  """Camera-to-world [N, 3, 4] (OpenCV axes) of LLFF's poses_bounds rows [N, 17]."""
  poses = poses_bounds[:, :15].reshape(-1, 3, 5)
  return np.concatenate([poses[:, :, :3] @ LLFF_TO_OPENCV, poses[:, :, 3:4]], -1)


def pose_errors(c2w: np.ndarray, reference: np.ndarray, distance: Optional[float] = None) -> Dict[str, np.ndarray]:
  """{'rotation_deg' [N], 'position' [N] (fraction of distance, default the reference's camera distance)} of
  cameras c2w [N, 3, 4] after their alignment to reference [N, 3, 4] (the same cameras, same order)."""
  distance = alignment.camera_distance(reference) if distance is None else distance
  found = alignment.errors(c2w, reference, distance)
  return {'rotation_deg': found['rotation_deg'], 'position': found['translation']}


def model_cameras(model) -> Tuple[list, np.ndarray]:
  """(image names in name order, their camera-to-world [N, 3, 4] in OpenCV axes) of a colmap_model.Model."""
  images = sorted(model.images.values(), key=lambda i: i.name)
  return [i.name for i in images], np.stack([colmap_model.camtoworld(i) for i in images])
