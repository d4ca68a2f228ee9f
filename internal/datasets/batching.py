"""Stateless, seeded training batches: the batch of step s depends only on (Config.np_rng_seed, s)."""

from typing import Any, NamedTuple, Optional

import numpy as np

from internal.cameras.records import Pixels
from internal.datasets import base, depth_prior, loader, random_poses, sfm_depth
from internal.rays import Rays

BATCHING_MODES = ('single_image', 'all_images')


class Batch(NamedTuple):
  """The training batch of one step (a pytree: with several devices every array is split along its first axis).

  Its rays come in families, each rendered once by the step: the training pixels of the data loss and, when a
  term needs them, RegNeRF's random-pose patches and the depth priors' rays. Those of training views carry their
  Pixels when the cameras are refined, which corrects them all before the loss terms.
  """
  rays: Rays                             # [B, ...] of training pixels.
  rgb: Any                               # [B, 3] their colours.
  pixels: Optional[Pixels] = None        # [B] where they are (camera refinement).
  patch_rays: Optional[Rays] = None      # [P, ps, ps, ...] RegNeRF's random-pose patches (depth smoothness).
  prior_rays: Optional[Rays] = None      # [Q, n, ...] patches of training views (depth ranking, Pearson).
  prior_pixels: Optional[Pixels] = None  # [Q, n] where they are (camera refinement).
  prior: Any = None                      # [Q, n] the depth maps' values there (Config.depth_prior_kind).
  sfm_rays: Optional[Rays] = None        # [K, ...] through structure-from-motion points (sparse depth).
  sfm_pixels: Optional[Pixels] = None    # [K] where they are (camera refinement).
  sfm_depth: Any = None                  # [K] the points' depths along the rays.
  sfm_weight: Any = None                 # [K] and their weights.


# The ray families of a Batch: (its rays field, its pixels field, or None for rays of no training view); a family's
# position salts its sampling key (training/renderer.py), so that a new one goes last.
FAMILIES = (('rays', 'pixels'), ('patch_rays', None), ('prior_rays', 'prior_pixels'), ('sfm_rays', 'sfm_pixels'))


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


def pixels_of(index: tuple, width: int) -> Pixels:
  """Pixels [...] (int32) of (image [...], flat pixel [...]) indices into images of the given width."""
  row, column = np.divmod(np.asarray(index[1]), width)
  return Pixels(*(np.asarray(x, np.int32) for x in (np.broadcast_to(index[0], row.shape), column, row)))


def make_batcher(dataset: base.Dataset, config):
  """callable(step) -> the Batch of the step: B = Config.batch_size pixels drawn with replacement (step >= 1), float32;
  RegNeRF's patches when depth smoothness is on, the depth priors' rays and values when one is on
  (make_prior_sampler), the Pixels of the training views' rays when the cameras are refined."""
  base.check_choice('Config.batching', config.batching, BATCHING_MODES)
  n, n_pixels = dataset.images.shape[0], dataset.height * dataset.width
  rays = Rays(*[np.reshape(x, (n, n_pixels, x.shape[-1])) for x in dataset.rays])
  rgb = dataset.images.reshape(n, n_pixels, 3)
  mode, batch_size, seed = config.batching, config.batch_size, config.np_rng_seed
  patches = random_poses.make_patch_sampler(dataset, config, loader.random_pose_cameras)
  crop = central_crop(dataset.height, dataset.width, config.precrop_frac) if config.precrop_steps > 0 else None
  priors = make_prior_sampler(dataset, config, rays)

  def batch(step: int) -> Batch:
    """The training batch of this step (steps 1..Config.precrop_steps: from the central crop only)."""
    rng = np.random.default_rng([seed, int(step)])
    allowed = crop if 0 < step <= config.precrop_steps else None
    index = pixel_indices(rng, mode, n, n_pixels, batch_size, allowed)
    return Batch(rays=Rays(*[x[index].astype(np.float32) for x in rays]), rgb=rgb[index].astype(np.float32),
                 pixels=pixels_of(index, dataset.width) if config.optimize_cameras else None,
                 patch_rays=None if patches is None else patches(step), **({} if priors is None else priors(step)))
  return batch


# ---------------------------------------------------------------- depth priors: patches and points of real views

PRIOR_STREAM = 3  # The depth-prior rays of step s come from np.random.default_rng([Config.np_rng_seed, s, 3]).


def patch_indices(rng: np.random.Generator, n_images: int, height: int, width: int, count: int,
                  size: int) -> tuple:
  """(image [count], flat pixel [count, size * size]) of count square patches, each inside one random image."""
  image = rng.integers(n_images, size=count)
  top, left = rng.integers(height - size + 1, size=count), rng.integers(width - size + 1, size=count)
  offsets = (np.arange(size)[:, None] * width + np.arange(size)[None]).reshape(-1)
  return image, (top * width + left)[:, None] + offsets


def make_prior_sampler(dataset: base.Dataset, config, rays: Rays):
  """callable(step) -> {Batch field: value} of the depth-prior part of a batch, or None when no depth-prior loss
  is on.

  rays: the dataset's Rays [N, H*W, ...]. With a dense prior: prior_rays [P, n, ...] and prior [P, n], P =
  Config.depth_prior_rays // n patches of n = Config.depth_patch_size**2 pixels of the training views; with the SfM
  prior: sfm_rays [K, ...], sfm_depth and sfm_weight [K], K = Config.depth_prior_rays rays drawn among the training
  pixels that observe a point; their pixels too (prior_pixels, sfm_pixels) when the cameras are refined.
  """
  dense, sparse = depth_prior.dense_losses_on(config), config.sfm_depth_loss_mult > 0
  if not (dense or sparse):
    return None
  n, height, width = len(dataset.ids), dataset.height, dataset.width
  size = config.depth_patch_size
  if dense and size > min(height, width):
    raise ValueError(f'Config.depth_patch_size = {size} exceeds the {width} x {height} training images')
  maps = depth_prior.load_maps(dataset, config).reshape(n, -1) if dense else None
  points = sfm_depth.training_prior(dataset, config) if sparse else None
  where = np.nonzero(points[1].reshape(-1))[0] if sparse else None
  take = lambda index: Rays(*[x[index].astype(np.float32) for x in rays])
  where_of = lambda index: pixels_of(index, width) if config.optimize_cameras else None

  def sample(step: int) -> dict:
    """The depth-prior rays of this step."""
    rng = np.random.default_rng([config.np_rng_seed, int(step), PRIOR_STREAM])
    out = {}
    if dense:
      image, pixel = patch_indices(rng, n, height, width, config.depth_prior_rays // size**2, size)
      index = (image[:, None], pixel)
      out.update(prior_rays=take(index), prior_pixels=where_of(index), prior=maps[index])
    if sparse:
      index = np.divmod(where[rng.integers(len(where), size=config.depth_prior_rays)], height * width)
      out.update(sfm_rays=take(index), sfm_pixels=where_of(index), sfm_depth=points[0].reshape(n, -1)[index],
                 sfm_weight=points[1].reshape(n, -1)[index])
    return out
  return sample
