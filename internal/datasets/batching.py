"""Stateless, seeded training batches: the batch of step s depends only on (Config.np_rng_seed, s)."""

import numpy as np

from internal.datasets import base, random_poses
from internal.rays import Rays

BATCHING_MODES = ('single_image', 'all_images')


def pixel_indices(rng: np.random.Generator, mode: str, n_images: int, n_pixels: int, batch_size: int) -> tuple:
  """(image [B], pixel [B]) indices: one random image per batch ('single_image') or any image ('all_images')."""
  if mode == 'single_image':
    return np.full(batch_size, rng.integers(n_images)), rng.integers(n_pixels, size=batch_size)
  return np.divmod(rng.integers(n_images * n_pixels, size=batch_size), n_pixels)


def make_batcher(dataset: base.Dataset, config):
  """callable(step) -> {'rays': Rays [B,...] f32, 'rgb': [B,3] f32}, pixels drawn with replacement.

  When a geometry loss needs them, the batch also holds 'patch_rays': Rays [P, ps, ps, ...] of random poses.
  """
  base.check_choice('Config.batching', config.batching, BATCHING_MODES)
  n, n_pixels = dataset.images.shape[0], dataset.height * dataset.width
  rays = Rays(*[np.reshape(x, (n, n_pixels, x.shape[-1])) for x in dataset.rays])
  rgb = dataset.images.reshape(n, n_pixels, 3)
  mode, batch_size, seed = config.batching, config.batch_size, config.np_rng_seed
  patches = random_poses.make_patch_sampler(dataset, config)

  def batch(step: int) -> dict:
    """The training batch of this step."""
    rng = np.random.default_rng([seed, int(step)])
    index = pixel_indices(rng, mode, n, n_pixels, batch_size)
    out = {'rays': Rays(*[x[index].astype(np.float32) for x in rays]), 'rgb': rgb[index].astype(np.float32)}
    if patches is not None:
      out['patch_rays'] = patches(step)
    return out
  return batch
