"""The viewer's cameras: viser's (a unit quaternion wxyz, a position, a vertical field of view, an aspect) against
this project's (camera-to-world [3,4], inverse intrinsics [3,3]), and the rays of any camera in a scene's ray space.

viser's cameras have OpenCV axes (+x right, +y down, looking down +z), as DTU's and COLMAP's; LLFF and Blender keep
OpenGL axes (+y up, looking down -z). A pixel's world direction does not depend on the axes its camera is written
in, so the rays made here equal the loaders' bit for bit for the same camera: a centred pinhole through the pixel
centres (Blender-layout scenes: Config.pixel_offset), DTU's origins moved onto their plane, and NDC rays mapped by
the training views' focal length and size (a forward scene's NDC space is its training cameras').
"""

import dataclasses
import math

import numpy as np

from internal.datasets import cameras, loader, pose_correction, raygen
from internal.rays import Rays

OPENGL_TO_OPENCV = np.diag([1., -1., -1.])


def rotation_matrix(wxyz) -> np.ndarray:
  """[3,3] rotation of a quaternion (w, x, y, z) [4], normalised first."""
  w, x, y, z = np.asarray(wxyz, np.float64) / np.linalg.norm(wxyz)
  return np.array([[1. - 2. * (y * y + z * z), 2. * (x * y - w * z), 2. * (x * z + w * y)],
                   [2. * (x * y + w * z), 1. - 2. * (x * x + z * z), 2. * (y * z - w * x)],
                   [2. * (x * z - w * y), 2. * (y * z + w * x), 1. - 2. * (x * x + y * y)]])


def quaternion(rotation) -> np.ndarray:
  """[4] unit quaternion (w, x, y, z) with w >= 0 of a rotation [3,3] (Shepperd's method: from the largest of the
  four squared components, stable at any angle)."""
  m = np.asarray(rotation, np.float64)
  squares = 1. + np.array([np.trace(m), 2. * m[0, 0] - np.trace(m), 2. * m[1, 1] - np.trace(m),
                           2. * m[2, 2] - np.trace(m)])
  k = int(np.argmax(squares))
  big = .5 * math.sqrt(squares[k])
  # For each component k: the sums and differences of off-diagonal pairs that give 4 * q_k * q_j.
  pairs = {0: (m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]),
           1: (m[2, 1] - m[1, 2], m[0, 1] + m[1, 0], m[0, 2] + m[2, 0]),
           2: (m[0, 2] - m[2, 0], m[0, 1] + m[1, 0], m[1, 2] + m[2, 1]),
           3: (m[1, 0] - m[0, 1], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1])}[k]
  others = [i for i in range(4) if i != k]
  q = np.empty(4)
  q[k] = big
  q[others] = np.array(pairs) / (4. * big)
  return q if q[0] >= 0 else -q


def to_opencv(camtoworlds, opengl: bool) -> np.ndarray:
  """[N,3,4] float64 cameras with OpenCV axes of cameras [N,3,4] with OpenGL axes (opengl) or OpenCV ones."""
  c2w = np.asarray(camtoworlds, np.float64)
  if not opengl:
    return c2w.copy()
  return np.concatenate([c2w[..., :3] @ OPENGL_TO_OPENCV, c2w[..., 3:]], -1)


def field_of_view(pixtocam, height: int) -> float:
  """The vertical field of view (radians) of a pinhole with inverse intrinsics pixtocam [3,3] and height rows."""
  return 2. * math.atan(.5 * height * abs(float(pixtocam[1][1])))


def view_camera(wxyz, position, fov: float, height: int, width: int) -> tuple:
  """(camera-to-world [3,4] with OpenCV axes, inverse intrinsics [3,3]) of viser's camera wxyz [4], position [3],
  vertical field of view fov (radians) at height x width pixels (a centred pinhole)."""
  c2w = np.concatenate([rotation_matrix(wxyz), np.asarray(position, np.float64)[:, None]], 1)
  return c2w, cameras.focal_pixtocam(.5 * height / math.tan(.5 * fov), height, width)


@dataclasses.dataclass(frozen=True)
class RayRule:
  """How a scene's rays follow from a camera: its ray space (world rays, DTU's origin plane, or NDC of the training
  views' focal length and size), the near and far of its training rays, and its pixel offset."""
  space: pose_correction.RaySpace
  near: float
  far: float
  pixel_offset: float = .5


def ray_rule(config, train_set) -> RayRule:
  """The RayRule of a run's scene, from its training split as loaded (the NDC focal length is read off its rays)."""
  offset = config.pixel_offset if loader.filed_as(config)[0] == 'blender' else .5  # Only Blender's rays use it.
  return RayRule(loader.ray_space(config, train_set), float(train_set.near), float(train_set.far), offset)


def camera_rays(camtoworld, pixtocam, height: int, width: int, rule: RayRule) -> Rays:
  """Rays [H,W,...] of a camera, camera-to-world [3,4] with OpenCV axes and inverse intrinsics [3,3], as the
  scene's loader makes them."""
  space = rule.space
  if space.ndc_focal:
    directions = raygen.camera_directions(pixtocam, height, width, opengl=False)
    return raygen.ndc_camera_rays(camtoworld, directions, space.ndc_focal, space.height, space.width)
  if space.plane_z is not None:
    return raygen.dtu_rays(camtoworld, pixtocam, height, width, rule.near, rule.far, space.plane_z)
  return raygen.pinhole_rays(camtoworld, pixtocam, height, width, rule.near, rule.far, False, rule.pixel_offset)


def world_lines(rays: Rays, rule: RayRule) -> tuple:
  """(points [...,3], directions [...,3]) float64: the world lines of rays (NDC rays mapped back: their origins lie
  where the world rays cross z = -1, raygen.convert_to_ndc)."""
  space = rule.space
  if not space.ndc_focal:
    return rays.origins.astype(np.float64), rays.directions.astype(np.float64)
  ndc = rays.origins.astype(np.float64)
  scale = np.array([space.width, space.height]) / (2. * space.ndc_focal)
  points = np.concatenate([ndc[..., :2] * scale, -np.ones_like(ndc[..., :1])], -1)
  return points, rays.viewdirs.astype(np.float64)


def nearest_point(points, directions) -> np.ndarray:
  """[3] the least-squares point nearest to the lines through points [N,3] along directions [N,3]."""
  unit = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
  projections = np.eye(3) - unit[:, :, None] * unit[:, None, :]
  return np.linalg.solve(projections.sum(0), np.einsum('nij,nj->i', projections, points))


def path_centres(path_rays: Rays, rule: RayRule) -> np.ndarray:
  """[F,3] camera centres of render-path frames, rays [F,H,W,...]: the point nearest to each frame's corner and
  centre rays."""
  height, width = path_rays.origins.shape[1:3]
  rows, cols = np.array([0, 0, height - 1, height - 1, height // 2]), np.array([0, width - 1, 0, width - 1, width // 2])
  points, directions = world_lines(Rays(*[x[:, rows, cols] for x in path_rays]), rule)
  return np.stack([nearest_point(p, d) for p, d in zip(points, directions)])
