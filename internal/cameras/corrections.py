"""Rigid corrections of cameras and the rays of the corrected cameras, for any loader's rays.

A correction (rotation Q [3,3], shift t [3]) of a camera c2w = [R | C] gives c2w' = [Q R | C + t]: the camera turns
about its own centre (Q in world axes) and moves by t. The rays of c2w' follow from the loaded rays of c2w without
knowing the camera model (pinhole, distorted, any loader): directions turn with the camera, origins move with it;
world radii stay (distances between neighbouring directions are rotation-invariant); DTU's origins go back onto
their world plane z = Config.near_origin; NDC rays are made again from the world rays (an NDC ray's viewdirs) and
their radii from their row and column neighbours' NDC origins, as caster.llff_rays makes them. The functions take
an array module xp (numpy or jax.numpy): the same code turns the loaded cameras (camera_noise.py) and builds the
rays inside the jitted training step, where gradients reach the corrections.
"""

import dataclasses
from typing import Optional

import numpy as np

from internal.cameras import caster
from internal.rays import Rays

SMALL_ANGLE2 = 1e-6  # Below this squared angle (radians) so3_exp uses its Taylor series (finite gradients at 0).


@dataclasses.dataclass(frozen=True)
class RaySpace:
  """How a scene's rays follow from its cameras: world rays; plane_z: origins on the world plane z = plane_z
  (DTU); ndc_focal > 0: LLFF's NDC rays of that focal length (pixels) for height x width images."""
  plane_z: Optional[float] = None
  ndc_focal: float = 0.
  height: int = 0
  width: int = 0


def so3_exp(omega, xp=np):
  """Rotations [...,3,3] of axis-angle vectors omega [...,3] (Rodrigues), with finite gradients at 0."""
  theta2 = xp.sum(omega * omega, axis=-1)[..., None, None]
  small = theta2 < SMALL_ANGLE2
  safe2 = xp.where(small, 1., theta2)
  theta = xp.sqrt(safe2)
  a = xp.where(small, 1. - theta2 / 6., xp.sin(theta) / theta)
  b = xp.where(small, .5 - theta2 / 24., (1. - xp.cos(theta)) / safe2)
  x, y, z = omega[..., 0], omega[..., 1], omega[..., 2]
  zero = xp.zeros_like(x)
  k = xp.stack([xp.stack([zero, -z, y], -1), xp.stack([z, zero, -x], -1), xp.stack([-y, x, zero], -1)], -2)
  return xp.eye(3, dtype=k.dtype) + a * k + b * (k @ k)


def rotation_angle(rotation: np.ndarray) -> np.ndarray:
  """Angles [...] (radians) of rotations [...,3,3], from their trace (float64)."""
  trace = np.trace(np.asarray(rotation, np.float64), axis1=-2, axis2=-1)
  return np.arccos(np.clip((trace - 1.) / 2., -1., 1.))


def corrected_cameras(camtoworlds: np.ndarray, rotations: np.ndarray, shifts: np.ndarray) -> np.ndarray:
  """[N,3,4] cameras [Q R | C + t] of c2w [N,3,4] corrected by rotations Q [N,3,3] and shifts t [N,3]."""
  c2w = np.asarray(camtoworlds, np.float64)
  return np.concatenate([np.asarray(rotations, np.float64) @ c2w[:, :, :3],
                         (c2w[:, :, 3] + np.asarray(shifts, np.float64))[..., None]], -1)


def _mat_vec(matrix, x, xp):
  """matrix [...,3,3] applied to x [...,3] (broadcast)."""
  return xp.sum(matrix * x[..., None, :], axis=-1)


def _ndc_origins(origins, directions, space: RaySpace, xp):
  """(NDC origins [...,3], NDC directions [...,3]) of world rays (caster.convert_to_ndc, over xp)."""
  return caster.convert_to_ndc(origins, directions, space.ndc_focal, space.height, space.width, xp=xp)


def corrected_rays(rays: Rays, rotation, centre, shift, space: RaySpace, neighbour_dirs=None, xp=np) -> Rays:
  """Rays [...] of cameras corrected by rotation [...,3,3] about their centre [...,3] and shift [...,3].

  rays: the loaded rays of the uncorrected cameras; neighbour_dirs [...,2,2,3]: for NDC rays, the world directions
  (loaded viewdirs) of the pixel pairs along rows and columns whose distance is the ray's radius (neighbour_pixels).
  """
  moved = centre + shift
  if space.ndc_focal:
    dirs = _mat_vec(rotation, rays.viewdirs, xp)
    origins, directions = _ndc_origins(moved, dirs, space, xp)
    turned = _mat_vec(rotation[..., None, None, :, :], neighbour_dirs, xp)
    ends = _ndc_origins(moved[..., None, None, :], turned, space, xp)[0]
    gaps = xp.sqrt(xp.sum((ends[..., 1, :] - ends[..., 0, :])**2, axis=-1))
    radii = xp.mean(gaps, axis=-1, keepdims=True) * (2. / np.sqrt(12.))
    return rays._replace(origins=origins, directions=directions, viewdirs=dirs, radii=radii)
  directions = _mat_vec(rotation, rays.directions, xp)
  origins = moved + _mat_vec(rotation, rays.origins - centre, xp)
  if space.plane_z is not None:
    origins = caster.shift_origins(origins, directions, space.plane_z)
  return rays._replace(origins=origins, directions=directions, viewdirs=_mat_vec(rotation, rays.viewdirs, xp))


def _pair(index: np.ndarray, length: int) -> np.ndarray:
  """[...,2] positions along an axis of the given length whose distance is index's (caster.neighbour_distances):
  (i, i + 1), and for the last the second-to-last pair."""
  first = np.where(index < length - 1, index, max(length - 3, 0))
  return np.stack([first, first + 1], -1)


def neighbour_pixels(pixel: np.ndarray, height: int, width: int) -> np.ndarray:
  """[...,2,2] flat indices of the pixel pairs along the row axis and the column axis whose distances give the
  radii of flat pixels [...] of a height x width image, as caster.neighbour_distances pairs them."""
  row, col = np.divmod(np.asarray(pixel), width)
  rows = _pair(row, height) * width + col[..., None]
  cols = row[..., None] * width + _pair(col, width)
  return np.stack([rows, cols], -2)


def camera_fields(index: tuple, viewdirs: np.ndarray, space: RaySpace, height: int, width: int) -> dict:
  """{'view': [B] int32 image of each ray, 'neighbour_dirs' (NDC rays): [B,2,2,3] world directions of the pixel
  pairs of its radius} of the batch's (image [B], flat pixel [B]) index, from the loaded viewdirs [N, H*W, 3]."""
  image, pixel = index
  fields = {'view': np.asarray(image, np.int32)}
  if space.ndc_focal:
    pairs = neighbour_pixels(pixel, height, width)
    fields['neighbour_dirs'] = viewdirs[image[:, None, None], pairs].astype(np.float32)
  return fields


def image_rays(rays: Rays, rotations, centres, shifts, space: RaySpace, xp=np) -> Rays:
  """Rays [N,H,W,...] of N cameras corrected by rotations [N,3,3] about centres [N,3] and shifts [N,3]."""
  n, height, width = rays.origins.shape[:3]
  neighbours = None
  if space.ndc_focal:
    index = neighbour_pixels(np.arange(height * width), height, width)
    neighbours = rays.viewdirs.reshape(n, height * width, 3)[:, index].reshape(n, height, width, 2, 2, 3)
  at = lambda x: x[:, None, None]
  return corrected_rays(rays, at(rotations), at(centres), at(shifts), space, neighbours, xp)
