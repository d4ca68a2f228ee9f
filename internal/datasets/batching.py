"""Stateless, seeded training batches: the batch of step s depends only on (Config.np_rng_seed, s)."""

import numpy as np

from internal.datasets import base, loader, pose_correction, random_poses
from internal.rays import Rays

BATCHING_MODES = ('single_image', 'all_images')


def pixel_indices(rng: np.random.Generator, mode: str, n_images: int, n_pixels: int, batch_size: int,
                  allowed=None) -> tuple:
  """(image [B], pixel [B]) indices: one random image per batch ('single_image') or any image ('all_images').

  allowed: flat pixel indices [K] to draw from (e.g. central_crop), or None for all n_pixels.
  """
  count = n_pixels if allowed is None else len(allowed)
  if mode == 'single_image':
    image, pixel = np.full(batch_size, rng.integers(n_images)), rng.integers(count, size=batch_size)
  else:
    image, pixel = np.divmod(rng.integers(n_images * count, size=batch_size), count)
  return image, (pixel if allowed is None else allowed[pixel])


def central_crop(height: int, width: int, frac: float) -> np.ndarray:
  """Flat pixel indices [h*w] of the central crop: rows [H//2 - d, H//2 + d) with d = int(H//2 * frac), same for W.

  This is NeRF's Blender warm-up crop (frac 0.5 of a 400 x 400 image: rows and columns 100..299).
  """
  dh, dw = int(height // 2 * frac), int(width // 2 * frac)
  if dh < 1 or dw < 1:
    raise ValueError(f'Config.precrop_frac = {frac} leaves no central crop of a {height} x {width} image')
  rows = np.arange(height // 2 - dh, height // 2 + dh)
  cols = np.arange(width // 2 - dw, width // 2 + dw)
  return (rows[:, None] * width + cols[None, :]).reshape(-1)


def make_batcher(dataset: base.Dataset, config):
  """callable(step) -> {'rays': Rays [B,...] f32, 'rgb': [B,3] f32}, pixels drawn with replacement (step >= 1).

  When a geometry loss needs them, the batch also holds 'patch_rays': Rays [P, ps, ps, ...] of random poses.
  """
  base.check_choice('Config.batching', config.batching, BATCHING_MODES)
  n, n_pixels = dataset.images.shape[0], dataset.height * dataset.width
  rays = Rays(*[np.reshape(x, (n, n_pixels, x.shape[-1])) for x in dataset.rays])
  rgb = dataset.images.reshape(n, n_pixels, 3)
  mode, batch_size, seed = config.batching, config.batch_size, config.np_rng_seed
  patches = random_poses.make_patch_sampler(dataset, config, loader.random_pose_cameras)
  crop = central_crop(dataset.height, dataset.width, config.precrop_frac) if config.precrop_steps > 0 else None
  space = loader.ray_space(config, dataset) if config.optimize_cameras else None

  def batch(step: int) -> dict:
    """The training batch of this step (steps 1..Config.precrop_steps: from the central crop only)."""
    rng = np.random.default_rng([seed, int(step)])
    allowed = crop if 0 < step <= config.precrop_steps else None
    index = pixel_indices(rng, mode, n, n_pixels, batch_size, allowed)
    out = {'rays': Rays(*[x[index].astype(np.float32) for x in rays]), 'rgb': rgb[index].astype(np.float32)}
    if patches is not None:
      out['patch_rays'] = patches(step)
    if space is not None:  # Camera refinement: the views of the rays (and NDC radii's neighbours).
      out.update(pose_correction.camera_fields(index, rays.viewdirs, space, dataset.height, dataset.width))
    return out
  return batch
