"""Pinhole ray generation (through pixel centres or integer pixels), DTU origin shift, LLFF NDC, as numpy Rays."""

import numpy as np

from internal.rays import Rays

OPENGL_FLIP = np.array([1., -1., -1.])  # OpenCV camera axes -> OpenGL (x right, y up, looking down -z).


def camera_directions(pixtocam: np.ndarray, height: int, width: int, opengl: bool,
                      offset: tuple = (.5, .5)) -> np.ndarray:
  """[H,W,3] camera-frame directions through pixel (x, y) + offset (centres), |z| = 1 (+1 OpenCV, -1 OpenGL)."""
  mat = np.asarray(pixtocam, np.float64) * (OPENGL_FLIP[:, None] if opengl else 1.)
  x = (np.arange(width, dtype=np.float64) + offset[0])[None, :, None]
  y = (np.arange(height, dtype=np.float64) + offset[1])[:, None, None]
  return x * mat[:, 0] + y * mat[:, 1] + mat[:, 2]


def world_directions(camtoworld: np.ndarray, cam_dirs: np.ndarray) -> np.ndarray:
  """Rotates camera directions [H,W,3] into the world by c2w [3,4]."""
  return mat_vec(np.asarray(camtoworld, np.float64)[:3, :3], cam_dirs)


def mat_vec(matrix: np.ndarray, x: np.ndarray) -> np.ndarray:
  """matrix [M,3] applied to every vector of x [...,3] -> [...,M] (x @ matrix.T, fast for tiny matrices)."""
  return np.einsum('ij,...j->...i', matrix, x)


def norm(x: np.ndarray) -> np.ndarray:
  """Euclidean norm over the last axis of x [...,3] -> [...]."""
  return np.sqrt(np.einsum('...i,...i->...', x, x))


def neighbour_distances(x: np.ndarray, axis: int) -> np.ndarray:
  """Distances [H,W] between neighbours of x [H,W,3] along axis; the last entry repeats the
  second-to-last distance as in the released code (the only one when the axis has length 2)."""
  d = norm(np.diff(x, axis=axis))
  pad = np.take(d, [max(d.shape[axis] - 2, 0)], axis=axis)
  return np.concatenate([d, pad], axis=axis)


def row_radii(directions: np.ndarray) -> np.ndarray:
  """[H,W,1] radii: distance between vertically adjacent directions x 2/sqrt(12)."""
  return neighbour_distances(directions, 0)[..., None] * 2. / np.sqrt(12.)


def shift_origins(origins: np.ndarray, directions: np.ndarray, plane_z: float) -> np.ndarray:
  """Moves origins [...,3] along directions [...,3] onto the world plane z = plane_z."""
  t = (plane_z - origins[..., 2:3]) / directions[..., 2:3]
  return origins + t * directions


def convert_to_ndc(origins: np.ndarray, directions: np.ndarray, focal: float, height: int, width: int,
                   near: float = 1., xp=np) -> tuple:
  """Forward-facing NDC: (origins [...,3] on z = -1, directions [...,3]) from world rays looking down -z (arrays
  of the module xp: numpy, or jax.numpy inside a jitted step)."""
  origins = shift_origins(origins, directions, -near)
  ox, oy, oz = xp.moveaxis(origins, -1, 0)
  dx, dy, dz = xp.moveaxis(directions, -1, 0)
  ndc_o = xp.stack([-2. * focal / width * ox / oz, -2. * focal / height * oy / oz, 1. + 2. * near / oz], -1)
  ndc_far = xp.stack([-2. * focal / width * dx / dz, -2. * focal / height * dy / dz, xp.ones_like(dz)], -1)
  return ndc_o, ndc_far - ndc_o


def ndc_radii(ndc_origins: np.ndarray) -> np.ndarray:
  """[H,W,1] radii from NDC origins [H,W,3]: mean of row and column neighbour distances x 2/sqrt(12)."""
  dx, dy = neighbour_distances(ndc_origins, 0), neighbour_distances(ndc_origins, 1)
  return (.5 * (dx + dy))[..., None] * 2. / np.sqrt(12.)


def pack_rays(origins, directions, viewdirs, radii, near: float, far: float) -> Rays:
  """Rays of float32 arrays [...,3]/[...,1] with lossmult 1 and constant near/far."""
  ones = np.ones(radii.shape, np.float32)
  return Rays(origins.astype(np.float32), directions.astype(np.float32), viewdirs.astype(np.float32),
              radii.astype(np.float32), ones, ones * np.float32(near), ones * np.float32(far))


def pinhole_rays(camtoworld, pixtocam, height, width, near, far, opengl, pixel_offset: float = .5) -> Rays:
  """Rays [H,W,...] of one pinhole camera through pixels (i, j) + pixel_offset: origins at its centre, unit
  viewdirs, row-neighbour radii."""
  offset = (pixel_offset, pixel_offset)
  return camera_rays(camtoworld, camera_directions(pixtocam, height, width, opengl, offset), near, far)


def camera_rays(camtoworld, cam_dirs: np.ndarray, near: float, far: float) -> Rays:
  """Rays [H,W,...] through camera-frame directions cam_dirs [H,W,3] of the camera c2w [3,4]: origins at its
  centre, unit viewdirs, row-neighbour radii."""
  dirs = world_directions(camtoworld, cam_dirs)
  origins = np.broadcast_to(np.asarray(camtoworld, np.float64)[:3, 3], dirs.shape)
  viewdirs = dirs / norm(dirs)[..., None]
  return pack_rays(origins, dirs, viewdirs, row_radii(dirs), near, far)


def dtu_rays(camtoworld, pixtocam, height, width, near, far, near_origin) -> Rays:
  """DTU rays [H,W,...] (OpenCV camera), origins moved onto the world plane z = near_origin."""
  rays = pinhole_rays(camtoworld, pixtocam, height, width, near, far, opengl=False)
  origins = shift_origins(rays.origins.astype(np.float64), rays.directions.astype(np.float64), near_origin)
  return rays._replace(origins=origins.astype(np.float32))


NDC_NEAR_FAR = (0., 1.)  # LLFF's NDC rays span t in [0, 1] whatever Config.near/far say.
NDC_BOX = ((-1., -1., -1.), (1., 1., .99))  # The space NDC rays cross (z = 1 is infinitely far): its region to mesh.


def llff_rays(camtoworld, pixtocam, height, width, focal) -> Rays:
  """LLFF NDC rays [H,W,...]: NDC origins/directions, NDC radii, world (unnormalised) viewdirs, near 0, far 1."""
  return ndc_camera_rays(camtoworld, camera_directions(pixtocam, height, width, opengl=True), focal, height, width)


def ndc_camera_rays(camtoworld, cam_dirs: np.ndarray, focal: float, height: int, width: int) -> Rays:
  """NDC rays [H,W,...] (as llff_rays) through OpenGL camera-frame directions cam_dirs [H,W,3] of c2w [3,4]."""
  dirs = world_directions(camtoworld, cam_dirs)
  origins = np.broadcast_to(np.asarray(camtoworld, np.float64)[:3, 3], dirs.shape)
  ndc_o, ndc_d = convert_to_ndc(origins, dirs, focal, height, width)
  return pack_rays(ndc_o, ndc_d, dirs, ndc_radii(ndc_o), *NDC_NEAR_FAR)


def stack_rays(rays_iter, count: int) -> Rays:
  """Stacks count Rays [H,W,...] from an iterator into preallocated Rays [N,H,W,...]."""
  out = None
  for i, rays in enumerate(rays_iter):
    if out is None:
      out = Rays(*[np.empty((count,) + x.shape, np.float32) for x in rays])
    for dst, src in zip(out, rays):
      dst[i] = src
  return out
