"""Rigid corrections of cameras and the rays of the corrected cameras.

A correction (rotation Q [3,3], shift t [3]) of a camera c2w = [R | C] gives c2w' = [Q R | C + t]: the camera turns
about its own centre (Q in world axes) and moves by t. The rays of c2w' follow from the rays cast for c2w
(caster.py): directions turn with the camera, origins move with it; world radii stay (distances between neighbouring
directions are rotation-invariant); DTU's origins go back onto their world plane; NDC rays are mapped again from
their world directions (an NDC ray keeps them as its viewdirs), their radii from the neighbours' directions, cast
from the cameras. The functions take an array module xp (numpy or jax.numpy): the same code turns the loaded cameras
(camera noise) and builds the rays inside the jitted training step, where gradients reach the corrections.
"""

import numpy as np

from internal.cameras import caster
from internal.cameras.records import Cameras, Pixels, RaySpace
from internal.rays import Rays

SMALL_ANGLE2 = 1e-6  # Below this squared angle (radians) so3_exp uses its Taylor series (finite gradients at 0).


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


def corrected_cameras(camtoworlds: np.ndarray, rotations: np.ndarray, shifts: np.ndarray) -> np.ndarray:
  """[N,3,4] cameras [Q R | C + t] of c2w [N,3,4] corrected by rotations Q [N,3,3] and shifts t [N,3]."""
  c2w = np.asarray(camtoworlds, np.float64)
  return np.concatenate([np.asarray(rotations, np.float64) @ c2w[:, :, :3],
                         (c2w[:, :, 3] + np.asarray(shifts, np.float64))[..., None]], -1)


def _turn(matrix, x, xp):
  """matrix [...,3,3] applied to x [...,3] (broadcast), as products summed: the arithmetic the refining step was
  pinned with (tests/test_pinned_steps.py), which caster.mat_vec's contraction would round differently."""
  return xp.sum(matrix * x[..., None, :], axis=-1)


def corrected_rays(rays: Rays, rotation, centre, shift, space: RaySpace, xp=np, cameras: Cameras = None,
                   pixels: Pixels = None) -> Rays:
  """Rays [...] of cameras corrected by rotation [...,3,3] about their centre [...,3] and shift [...,3].

  rays: the rays cast through pixels [...] of the uncorrected cameras (NDC rays need both, for their radii).
  """
  moved = centre + shift
  if space.ndc_focal:
    dirs = _turn(rotation, rays.viewdirs, xp)
    rows, columns = (_turn(rotation[..., None, :, :], caster.neighbour_directions(cameras, pixels, space, axis, xp),
                           xp) for axis in (caster.ROW, caster.COLUMN))
    origins, directions, viewdirs, radii = caster.ndc_fields(moved, dirs, rows, columns, space, xp)
    return rays._replace(origins=origins, directions=directions, viewdirs=viewdirs, radii=radii)
  directions = _turn(rotation, rays.directions, xp)
  origins = moved + _turn(rotation, rays.origins - centre, xp)
  if space.plane_z is not None:
    origins = caster.shift_origins(origins, directions, space.plane_z)
  return rays._replace(origins=origins, directions=directions, viewdirs=_turn(rotation, rays.viewdirs, xp))


def corrected_image_rays(rays: Rays, cameras: Cameras, rotations, shifts, space: RaySpace) -> Rays:
  """Rays [N,H,W,...] (float32) of the N cameras' images corrected by rotations [N,3,3] and shifts [N,3]; rays: their
  images' rays as cast (numpy, float64 arithmetic)."""
  image = caster.image_pixels(0, space.height, space.width)
  pixels = Pixels(np.arange(len(rotations))[:, None, None], image.x[None], image.y[None])
  centres = np.asarray(cameras.camtoworlds, np.float64)[:, :, 3]
  at = lambda x: np.asarray(x, np.float64)[:, None, None]
  moved = corrected_rays(rays, at(rotations), centres[:, None, None], at(shifts), space, np, cameras, pixels)
  return Rays(*[np.asarray(x, np.float32) for x in moved])
