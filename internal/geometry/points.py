"""A trained field as a point cloud: the expected depth of rendered views, kept where the ray is nearly opaque and
two or more training views agree, coloured by the radiance, with a COLMAP model (cameras, images, tracks).

Each view's rendered expected depth gives a world point per pixel (NDC depths converted back to the world). A
point agrees with a training view when it lies in front of that camera inside its image, the view's own rendering
there is nearly opaque, and the view's rendered point at that pixel has the same camera depth within a relative
tolerance; the training views that agree form its track (its own view among them, for training views). Points of
fewer than min_views agreeing training views are dropped: those are what only one view claims. The tracks'
observations are the points' projections, so the model's reprojection errors are 0.

Host memory: a depth map and an opacity mask per training view (MAP_BYTES a pixel), one view's candidates at a
time (CANDIDATE_BYTES a pixel and a training view) and the kept points (POINT_BYTES a point and a training view),
at most max_points of them: host_bytes gives the total before any work.
"""

import dataclasses
from typing import List, Optional

import numpy as np

from internal.cameras import algebra
from internal.datasets import colmap_model
from internal.evaluation import depth_metrics

MAP_BYTES = 5          # f32 camera depth + bool opacity per pixel of a training view.
CANDIDATE_BYTES = 64   # Per pixel of the view being checked, per training view (projections, depths, masks).
POINT_BYTES = 48       # Per kept point: position, colour, normal; plus per training view its observation.
OPENGL_TO_OPENCV = np.diag([1., -1., -1.])


@dataclasses.dataclass
class View:
  """One rendered view: world points [H,W,3], rgb [H,W,3], opacity [H,W], unit normals [H,W,3] (None: unknown);
  for a training view its image name, OpenCV camera-to-world [3,4] and intrinsics K [3,3] (pixel centres at +0.5,
  COLMAP's convention); None for a view of the render path."""
  points: np.ndarray
  rgb: np.ndarray
  acc: np.ndarray
  normals: Optional[np.ndarray]
  name: Optional[str] = None
  camtoworld: Optional[np.ndarray] = None
  intrinsics: Optional[np.ndarray] = None


def host_bytes(n_train: int, train_pixels: int, view_pixels: int, max_points: int) -> int:
  """Host memory the point cloud of n_train training views of train_pixels each needs, its largest view holding
  view_pixels, at most max_points kept."""
  return (n_train * train_pixels * MAP_BYTES + view_pixels * n_train * CANDIDATE_BYTES
          + max_points * POINT_BYTES * (1 + n_train))


def opencv_camtoworld(camtoworld: np.ndarray, centre_direction: np.ndarray) -> np.ndarray:
  """[3,4] the camera with OpenCV axes (+z forward, +y down): camtoworld as given when the ray through the image
  centre, centre_direction [3] (world), points along its +z, else (OpenGL) with y and z flipped."""
  c2w = np.asarray(camtoworld, np.float64)
  if np.dot(c2w[:, 2], centre_direction) > 0:
    return c2w.copy()
  return np.concatenate([c2w[:, :3] @ OPENGL_TO_OPENCV, c2w[:, 3:]], 1)


def world_points(rays, distance: np.ndarray, camtoworld: np.ndarray, ndc: bool) -> np.ndarray:
  """World points [H,W,3] at the rendered distances [H,W] along one view's rays [H,W,...] (NDC converted back)."""
  distance = np.asarray(distance, np.float64)
  if not ndc:
    return rays.origins.astype(np.float64) + distance[..., None] * rays.directions.astype(np.float64)
  centre = np.asarray(camtoworld, np.float64)[:3, 3]
  directions = rays.viewdirs.astype(np.float64)
  t = depth_metrics.ndc_distance_to_depth(distance, rays.origins.astype(np.float64),
                                          rays.directions.astype(np.float64), centre, directions)
  return centre + t[..., None] * directions


def project(view: View, points: np.ndarray) -> tuple:
  """(pixel coordinates [P, 2] (x, y; COLMAP's), camera z-depth [P]) of world points [P, 3] in view."""
  local = (points - view.camtoworld[:, 3]) @ view.camtoworld[:, :3]
  z = local[:, 2]
  with np.errstate(divide='ignore', invalid='ignore'):
    pixel = (local @ view.intrinsics.T)[:, :2] / z[:, None]
  return pixel, z


def agreement(train: List[View], depth_maps: List[np.ndarray], points: np.ndarray, tolerance: float) -> tuple:
  """(agrees [P, V] bool, pixels [P, V, 2] f32) of world points [P, 3] with each training view: in front, inside
  its image, where its rendering is opaque (depth_maps: camera depth [H,W], 0 where not opaque), at that depth
  within tolerance (relative)."""
  agrees = np.zeros((len(points), len(train)), bool)
  pixels = np.zeros((len(points), len(train), 2), np.float32)
  for j, (view, depth) in enumerate(zip(train, depth_maps)):
    pixel, z = project(view, points)
    height, width = depth.shape
    col, row = np.floor(pixel[:, 0]), np.floor(pixel[:, 1])
    inside = (z > 0) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    seen = np.where(inside, depth[np.clip(row, 0, height - 1).astype(int), np.clip(col, 0, width - 1).astype(int)],
                    0.)
    agrees[:, j] = inside & (seen > 0) & (np.abs(seen - z) <= tolerance * z)
    pixels[:, j] = pixel
  return agrees, pixels


def camera_depth(view: View) -> np.ndarray:
  """Camera z-depth [H,W] of a view's rendered points."""
  return (view.points - view.camtoworld[:, 3]) @ view.camtoworld[:, 2]


def cloud(train: List[View], others: List[View], min_opacity: float, tolerance: float, min_views: int,
          max_points: int, rng: np.random.Generator) -> dict:
  """The point cloud of the training views and other views (the render path's): {'points' [P,3], 'colours'
  [P,3] in [0,1], 'normals' [P,3] or None, 'agrees' [P, V] bool, 'pixels' [P, V, 2]} of the opaque pixels of
  each view that at least min_views training views agree with, at most max_points (each view keeps an equal
  share, drawn at random)."""
  depth_maps = [np.where(v.acc >= min_opacity, camera_depth(v), 0.).astype(np.float32) for v in train]
  views = train + others
  share = max(max_points // len(views), 1)
  kept = {'points': [], 'colours': [], 'normals': [], 'agrees': [], 'pixels': []}
  for view in views:
    opaque = np.flatnonzero(view.acc.reshape(-1) >= min_opacity)
    candidates = view.points.reshape(-1, 3)[opaque]
    agrees, pixels = agreement(train, depth_maps, candidates, tolerance)
    good = np.flatnonzero(agrees.sum(1) >= min_views)
    good = np.sort(rng.choice(good, share, replace=False)) if len(good) > share else good
    kept['points'].append(candidates[good])
    kept['colours'].append(np.clip(view.rgb.reshape(-1, 3)[opaque[good]], 0., 1.))  # White backgrounds add 1 - acc.
    kept['normals'].append(None if view.normals is None else view.normals.reshape(-1, 3)[opaque[good]])
    kept['agrees'].append(agrees[good])
    kept['pixels'].append(pixels[good])
  normals = kept.pop('normals')
  out = {key: np.concatenate(values) for key, values in kept.items()}
  out['normals'] = None if any(n is None for n in normals) else np.concatenate(normals)
  return out


def colmap_of(train: List[View], sizes: List[tuple], found: dict) -> colmap_model.Model:
  """The COLMAP model of a cloud: a PINHOLE camera per training view scaled to its image file's size (height,
  width) in sizes, its pose, its observations of the points (their projections) and the points' tracks."""
  cameras, images = {}, {}
  scales = []
  for k, (view, (height, width)) in enumerate(zip(train, sizes)):
    scale = width / view.points.shape[1]
    fx, fy, cx, cy = (view.intrinsics[0, 0], view.intrinsics[1, 1], view.intrinsics[0, 2], view.intrinsics[1, 2])
    cameras[k + 1] = colmap_model.Camera(k + 1, 'PINHOLE', int(width), int(height),
                                         np.array([fx, fy, cx, cy]) * scale)
    rotation = view.camtoworld[:, :3].T
    images[k + 1] = colmap_model.Image(k + 1, algebra.rotation_to_quaternion(rotation),
                                       -rotation @ view.camtoworld[:, 3], k + 1, view.name,
                                       np.zeros(0, colmap_model.POINT2D))
    scales.append(scale)
  observations = [[] for _ in train]
  points = {}
  colours = np.round(np.clip(found['colours'], 0., 1.) * 255.).astype(np.uint8)
  for p in range(len(found['points'])):
    track = []
    for k in np.flatnonzero(found['agrees'][p]):
      x, y = found['pixels'][p, k] * scales[k]
      track.append((k + 1, len(observations[k])))
      observations[k].append((x, y, p + 1))
    points[p + 1] = colmap_model.Point3D(p + 1, found['points'][p].astype(np.float64), colours[p], 0.,
                                         np.array(track, colmap_model.TRACK))
  for k, image in enumerate(images.values()):
    image.points2d = np.array(observations[k], colmap_model.POINT2D)
  return colmap_model.Model(cameras, images, points)
