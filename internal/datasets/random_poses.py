"""RegNeRF's random poses and the patches of rays drawn from them each step (never all rays at once).

Poses are drawn once from np.random.default_rng([Config.np_rng_seed, POSES_STREAM]); the patches of step s from
np.random.default_rng([Config.np_rng_seed, s, PATCHES_STREAM]), so a resumed run draws the same patches. A patch's
rays are cast as the training images' (the dataset's RaySpace) with RegNeRF's two differences: unit viewdirs for
NDC rays, and radii from the next pixel on a patch's last row and column as on its others.
"""

import dataclasses

import numpy as np

from internal.cameras import algebra, caster
from internal.cameras.records import Pixels, RaySpace
from internal.datasets import base
from internal.rays import Rays

POSES_STREAM = 1
PATCHES_STREAM = 2
FOCUS_JITTER_STD = 0.125


def needs_patches(config) -> bool:
  """Whether Config asks for the depth-smoothness loss (as released: a nonzero mult or the decay schedule)."""
  return config.depth_tvnorm_loss_mult != 0 or config.depth_tvnorm_decay


def _box_positions(poses: np.ndarray, u: np.ndarray) -> np.ndarray:
  """[n,3] positions c2w_avg @ [r * u, 1], r = max |camera position| per axis, u [n,3] in [-1, 1]."""
  radii = np.abs(poses[:, :3, 3]).max(0)
  c2w = algebra.to_homogeneous(algebra.poses_avg(poses))
  local = np.concatenate([radii * u, np.ones((len(u), 1))], axis=-1)
  return (local @ c2w.T)[:, :3]


def dtu_random_poses(poses: np.ndarray, n: int, rng: np.random.Generator, radius: float,
                     jitter: bool) -> np.ndarray:
  """[n,3,4] OpenCV poses in the box of poses [N,3,4] (render-path type), +z towards the (jittered) focus point."""
  positions = _box_positions(poses, 2. * radius * (rng.random((n, 3)) - .5))
  focus = algebra.focus_point(poses) + (rng.normal(size=(n, 3)) * FOCUS_JITTER_STD if jitter else 0.)
  up = poses[:, :3, 1].mean(0)
  return np.stack([algebra.viewmatrix(f - p, up, p) for f, p in zip(np.broadcast_to(focus, (n, 3)), positions)])


def llff_random_poses(poses: np.ndarray, bounds: np.ndarray, n: int, rng: np.random.Generator,
                      keep_last_only: bool) -> np.ndarray:
  """[n,3,4] OpenGL poses in the box of poses [N,3,4] looking at the spiral's focus depth; [1,3,4] if keep_last_only.

  keep_last_only reproduces the released LLFF loader, which keeps only the last of its n draws.
  """
  focus = 1. / ((1. - .75) / (bounds.min() * .9) + .75 / (bounds.max() * 5.))
  positions = _box_positions(poses, 2. * rng.random((n, 3)) - 1.)
  if keep_last_only:
    positions = positions[-1:]
  lookat = (algebra.to_homogeneous(algebra.poses_avg(poses)) @ np.array([0., 0., -focus, 1.]))[:3]
  up = poses[:, :3, 1].mean(0)
  return np.stack([algebra.viewmatrix(p - lookat, up, p) for p in positions])


def patch_space(space: RaySpace) -> RaySpace:
  """The RaySpace of RegNeRF's patches in a scene of space: unit viewdirs, radii from the next pixel everywhere."""
  return dataclasses.replace(space, unit_viewdirs=True, released_edges=False)


def patch_pixels(pose, x0, y0, size: int) -> Pixels:
  """Pixels [P, size, size] of P square patches: pose [P] (a camera index), rows from y0 [P], columns from x0 [P]."""
  at, offsets = lambda start: np.asarray(start)[:, None, None], np.arange(size)
  return Pixels(at(pose), at(x0) + offsets[None, None], at(y0) + offsets[None, :, None])


def check_random_rays(config) -> None:
  """Raises ValueError naming the settings when Config asks for random-pose patches but forbids random rays."""
  if not config.load_random_rays:
    raise ValueError('Config.depth_tvnorm_loss_mult / depth_tvnorm_decay need random-pose patches; '
                     'set Config.load_random_rays = True (or turn the depth-smoothness loss off)')


def make_patch_sampler(dataset: base.Dataset, config, scene_cameras):
  """callable(step) -> Rays [P, ps, ps, ...] f32 of P random-pose patches, or None when no loss needs them.

  scene_cameras: (dataset, config, rng) -> the scene's random poses as Cameras in the dataset's axes and RaySpace
  (the loader's, see loader.random_pose_cameras).
  """
  if not needs_patches(config):
    return None
  check_random_rays(config)
  cameras = scene_cameras(dataset, config, np.random.default_rng([config.np_rng_seed, POSES_STREAM]))
  space = patch_space(dataset.space)
  size, height, width = config.patch_size, dataset.height, dataset.width
  count = config.batch_size_random // size**2

  def patches(step: int) -> Rays:
    """The random-pose patches of this step."""
    rng = np.random.default_rng([config.np_rng_seed, int(step), PATCHES_STREAM])
    pose = rng.integers(len(cameras.camtoworlds), size=count)
    x0, y0 = rng.integers(width - size + 1, size=count), rng.integers(height - size + 1, size=count)
    return caster.cast(cameras, patch_pixels(pose, x0, y0, size), space)
  return patches
