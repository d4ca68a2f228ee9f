"""The viewer's cameras: viser's (a unit quaternion wxyz, a position, a vertical field of view, an aspect) against
this project's (camera-to-world [3,4], inverse intrinsics [3,3]), and the rays of any camera in a scene's RaySpace.

viser's cameras have OpenCV axes (+x right, +y down, looking down +z), as DTU's and COLMAP's; LLFF and Blender keep
OpenGL axes (+y up, looking down -z). A browser's camera is cast by the camera room's one caster
(internal/cameras/caster.py) in the RaySpace of the run's training views, as their loader cast theirs: a pixel's
world direction does not depend on the axes its camera is written in, so at the training views' size the rays equal
the loader's (and render.py's) bit for bit for the same camera: world rays, DTU's origins on their plane, NDC rays.
A frame of another size keeps the scene's space (frame_space).
"""

import dataclasses
import math

import numpy as np

from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.rays import Rays

OPENGL_TO_OPENCV = np.diag([1., -1., -1.])


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
  c2w = np.concatenate([algebra.quaternion_to_rotation(wxyz), np.asarray(position, np.float64)[:, None]], 1)
  return c2w, algebra.focal_pixtocam(.5 * height / math.tan(.5 * fov), height, width)


def frame_space(space: RaySpace, height: int, width: int) -> RaySpace:
  """The RaySpace of a height x width frame of cameras with OpenCV axes in a scene's space: world rays at the
  frame's size; NDC rays keep the training views' NDC map (its focal length and their size, which the released
  radii rule also reads), so that at another size a ray's radius comes from the next pixel's on the last row and
  column too."""
  if not space.ndc_focal:
    return dataclasses.replace(space, opengl=False, height=height, width=width)
  same_size = (height, width) == (space.height, space.width)
  return dataclasses.replace(space, opengl=False, released_edges=space.released_edges and same_size)


def camera_rays(camtoworld, pixtocam, height: int, width: int, space: RaySpace) -> Rays:
  """Rays [H,W,...] of a camera, camera-to-world [3,4] with OpenCV axes and inverse intrinsics [3,3] (a pinhole),
  in a scene's RaySpace (its training views')."""
  cameras = Cameras(np.asarray(camtoworld, np.float64)[None], np.asarray(pixtocam, np.float64)[None])
  return caster.cast(cameras, caster.image_pixels(0, height, width), frame_space(space, height, width))


def world_lines(rays: Rays, space: RaySpace) -> tuple:
  """(points [...,3], directions [...,3]) float64: the world lines of rays (NDC rays mapped back: their origins lie
  where the world rays cross z = -1, caster.convert_to_ndc)."""
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


def path_centres(path_rays: Rays, space: RaySpace) -> np.ndarray:
  """[F,3] camera centres of render-path frames, rays [F,H,W,...] in the scene's space: the point nearest to each
  frame's corner and centre rays."""
  height, width = path_rays.origins.shape[1:3]
  rows, cols = np.array([0, 0, height - 1, height - 1, height // 2]), np.array([0, width - 1, 0, width - 1, width // 2])
  points, directions = world_lines(Rays(*[x[:, rows, cols] for x in path_rays]), space)
  return np.stack([nearest_point(p, d) for p, d in zip(points, directions)])
