"""RegNeRF's random poses and the patches of rays drawn from them each step (never all rays at once).

Poses are drawn once from np.random.default_rng([Config.np_rng_seed, POSES_STREAM]); the patches of step s from
np.random.default_rng([Config.np_rng_seed, s, PATCHES_STREAM]), so a resumed run draws the same patches.
"""

import numpy as np

from internal.cameras import algebra, caster
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


def patch_rays(camtoworld, pixtocam, height: int, width: int, x0: int, y0: int, size: int, near: float,
               far: float, ndc_focal: float = 0., near_origin: float = 0.) -> Rays:
  """Rays [size,size,...] of pixels [y0, y0+size) x [x0, x0+size) of a camera of the full image's geometry.

  ndc_focal > 0: LLFF (OpenGL camera, NDC rays over the full image, unit viewdirs as RegNeRF's random rays);
  else DTU (OpenCV camera, origins on z = near_origin). Radii use the next pixel, as for a full image's inner
  pixels (on the last image row or column the neighbour lies just outside instead of repeating a difference).
  """
  cam_dirs = caster.camera_directions(pixtocam, size + 1, size + 1, ndc_focal > 0, (x0 + .5, y0 + .5))
  dirs = caster.world_directions(camtoworld, cam_dirs)
  origins = np.broadcast_to(np.asarray(camtoworld, np.float64)[:3, 3], dirs.shape)
  viewdirs = dirs / caster.norm(dirs)[..., None]
  if ndc_focal > 0:
    origins, dirs = caster.convert_to_ndc(origins, dirs, ndc_focal, height, width)
    radii = caster.ndc_radii(origins)
  else:
    radii = caster.row_radii(dirs)
    origins = caster.shift_origins(origins, dirs, near_origin)
  crop = lambda x: x[:size, :size]
  return caster.pack_rays(crop(origins), crop(dirs), crop(viewdirs), crop(radii), near, far)


def check_random_rays(config) -> None:
  """Raises ValueError naming the settings when Config asks for random-pose patches but forbids random rays."""
  if not config.load_random_rays:
    raise ValueError('Config.depth_tvnorm_loss_mult / depth_tvnorm_decay need random-pose patches; '
                     'set Config.load_random_rays = True (or turn the depth-smoothness loss off)')


def make_patch_sampler(dataset: base.Dataset, config, scene_cameras):
  """callable(step) -> Rays [P, ps, ps, ...] f32 of P random-pose patches, or None when no loss needs them.

  scene_cameras: (dataset, config, rng) -> (random poses [n,3,4], pixtocam [3,3], NDC focal or 0) of the scene
  (the loader's, see loader.random_pose_cameras).
  """
  if not needs_patches(config):
    return None
  check_random_rays(config)
  poses, pixtocam, ndc_focal = scene_cameras(dataset, config, np.random.default_rng([config.np_rng_seed,
                                                                                     POSES_STREAM]))
  size, height, width = config.patch_size, dataset.height, dataset.width
  count = config.batch_size_random // size**2

  def patches(step: int) -> Rays:
    """The random-pose patches of this step."""
    rng = np.random.default_rng([config.np_rng_seed, int(step), PATCHES_STREAM])
    pose = rng.integers(len(poses), size=count)
    x0, y0 = rng.integers(width - size + 1, size=count), rng.integers(height - size + 1, size=count)
    rays = [patch_rays(poses[p], pixtocam, height, width, x, y, size, dataset.near, dataset.far, ndc_focal,
                       config.near_origin) for p, x, y in zip(pose, x0, y0)]
    return Rays(*[np.stack(field) for field in zip(*rays)])
  return patches
