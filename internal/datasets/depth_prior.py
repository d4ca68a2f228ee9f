"""Dense depth priors of the training views: one map per image, from whatever monocular model the user trusts.

Config.depth_prior_dir holds `<image stem>.npy` (a float or integer array [h, w], [h, w, 1] or [1, h, w]) or
`<image stem>.png` (16-bit grey) per training image, at any size with the image's aspect ratio; each map is
resampled to the training resolution (area average when it shrinks, bilinear when it grows) over its valid
values only, so a hole never bleeds into its neighbours. 0 and non-finite values are "no prior" there; a pixel
keeps a prior where at least half of it is covered by valid values. Maps are read for the training views only.
Config.depth_prior_kind says whether they hold depth or disparity; either is known only up to scale and shift,
which the ranking and Pearson losses ignore (the maps' only readers): so each map is rescaled by the power of two
that brings its largest valid magnitude into [1, 2), which float32 holds whatever the map's units (a map of 1e40s
trains as one of 1s; exactly so, a power of two scaling every step of the losses exactly). Every bad map is one
DatasetError naming its file, as is one whose values span more than float32 holds.
"""

import os
import warnings

import numpy as np
import png  # pypng: 16-bit PNGs at their full depth.

from internal.datasets import base

KINDS = ('depth', 'disparity')
SUFFIXES = ('.npy', '.png')
MIN_COVER = .5  # A resampled pixel keeps a prior where valid values cover at least this fraction of it.


def dense_losses_on(config) -> bool:
  """Whether a loss reads the maps of Config.depth_prior_dir (ranking or Pearson)."""
  return config.depth_rank_loss_mult > 0 or config.depth_pearson_loss_mult > 0


def any_on(config) -> bool:
  """Whether a depth-prior loss is on: a dense one or the structure-from-motion points'."""
  return dense_losses_on(config) or config.sfm_depth_loss_mult > 0


def check_settings(config) -> None:
  """ValueError naming the setting when the depth-prior settings cannot work together; warns when the maps or
  the model would not be read."""
  if dense_losses_on(config) and not config.depth_prior_dir:
    raise ValueError('Config.depth_rank_loss_mult / depth_pearson_loss_mult > 0 need depth maps: set '
                     'Config.depth_prior_dir to the folder of one map per training image (docs/running.md)')
  size, rays = config.depth_patch_size, config.depth_prior_rays
  if dense_losses_on(config) and (size < 2 or rays < size**2):
    raise ValueError(f'Config.depth_patch_size = {size} and Config.depth_prior_rays = {rays}: the ranking and '
                     'Pearson losses compare pixels of patches of 2 x 2 or more, depth_prior_rays // '
                     'depth_patch_size**2 of them a step (at least one)')
  if config.depth_prior_dir and config.depth_prior_kind not in KINDS:
    raise ValueError(f'Config.depth_prior_kind = {config.depth_prior_kind!r}; expected one of {list(KINDS)}: '
                     f'what the maps in Config.depth_prior_dir = {config.depth_prior_dir!r} hold (monocular '
                     "models such as MiDaS, DPT and Depth Anything give 'disparity')")
  if config.depth_prior_dir and not dense_losses_on(config):
    warnings.warn(f'Config.depth_prior_dir = {config.depth_prior_dir!r} is not read: Config.depth_rank_loss_mult '
                  'and depth_pearson_loss_mult are both 0', stacklevel=3)
  if config.sfm_depth_loss_mult > 0 and config.dataset_loader != 'capture':
    raise ValueError(f'Config.sfm_depth_loss_mult = {config.sfm_depth_loss_mult} needs a capture\'s structure-'
                     "from-motion points (Config.dataset_loader = 'capture'); this Config.dataset_loader = "
                     f'{config.dataset_loader!r}. Other scenes can use depth maps (Config.depth_prior_dir)')
  if config.sfm_depth_model and config.sfm_depth_loss_mult <= 0:
    warnings.warn(f'Config.sfm_depth_model = {config.sfm_depth_model!r} is not read: Config.sfm_depth_loss_mult '
                  'is 0', stacklevel=3)


def map_path(folder: str, image_path: str) -> str:
  """The map of an image: <folder>/<image stem>.npy, else .png; DatasetNotFoundError naming both."""
  stem = os.path.splitext(os.path.basename(image_path))[0]
  candidates = [os.path.join(folder, stem + suffix) for suffix in SUFFIXES]
  for path in candidates:
    if os.path.isfile(path):
      return path
  raise base.DatasetNotFoundError(f'Config.depth_prior_dir: no depth map of training image {image_path!r}; '
                                  f'expected {candidates[0]!r} or {candidates[1]!r}')


def _read_png(path: str) -> tuple:
  """(values f64 [h, w, planes], pypng's info) of a PNG at its full depth."""
  width, height, rows, info = png.Reader(filename=path).asDirect()
  return np.vstack([np.asarray(row, np.float64) for row in rows]).reshape(height, width, -1), info


def read_map(path: str) -> np.ndarray:
  """A depth map file as f64 [h, w] (values as stored, 0 and non-finite = none); DatasetError naming it."""
  try:
    values, info = _read_png(path) if path.endswith('.png') else (np.load(path, allow_pickle=False), None)
  except (OSError, ValueError, EOFError, png.Error) as err:
    raise base.DatasetError(f'cannot read depth map {path!r} (expected a .npy array or a 16-bit PNG): '
                            f'{err}') from err
  if info is not None and (info['bitdepth'] != 16 or info['planes'] != 1):
    raise base.DatasetError(f'depth map {path!r} is a {info["bitdepth"]}-bit PNG with {info["planes"]} channel(s); '
                            'expected 16-bit grey (or a float .npy), so that it keeps its precision')
  values = np.asarray(values)
  shape = values.shape
  if values.ndim == 3 and 1 in (shape[0], shape[-1]):
    values = values.reshape(shape[1:] if shape[0] == 1 else shape[:2])
  if values.ndim != 2 or min(values.shape) < 1 or not np.issubdtype(values.dtype, np.number) or (
      np.iscomplexobj(values)):
    raise base.DatasetError(f'depth map {path!r} holds a {values.dtype} array of shape {list(shape)}; expected '
                            'real numbers of shape [H, W] (or [H, W, 1], [1, H, W])')
  return values.astype(np.float64)


def _axis_weights(src: int, dst: int) -> np.ndarray:
  """[dst, src] rows summing to 1: each output sample's share of the input (area when shrinking, linear
  between pixel centres when growing)."""
  if dst <= src:
    edges = np.arange(dst + 1) * (src / dst)
    index = np.arange(src)[None]
    weights = np.clip(np.minimum(edges[1:, None], index + 1) - np.maximum(edges[:-1, None], index), 0., None)
  else:
    position = np.clip((np.arange(dst) + .5) * (src / dst) - .5, 0., src - 1)
    low = np.floor(position).astype(int)
    weights = np.zeros((dst, src))
    np.add.at(weights, (np.arange(dst), low), 1. - (position - low))
    np.add.at(weights, (np.arange(dst), np.minimum(low + 1, src - 1)), position - low)
  return weights / weights.sum(1, keepdims=True)


def resample(values: np.ndarray, height: int, width: int) -> np.ndarray:
  """f64 [height, width] of a map [h, w] over its valid values (finite, nonzero); 0 where too few cover a pixel."""
  valid = np.isfinite(values) & (values != 0)
  rows, cols = _axis_weights(values.shape[0], height), _axis_weights(values.shape[1], width)
  cover = rows @ valid @ cols.T
  total = rows @ np.where(valid, values, 0.) @ cols.T
  return np.where(cover >= MIN_COVER, total / np.maximum(cover, 1e-12), 0.)


def rescaled(values: np.ndarray) -> np.ndarray:
  """values [h, w] (some valid) times the power of two that brings their largest valid magnitude into [1, 2)."""
  largest = np.abs(values[np.isfinite(values) & (values != 0)]).max()
  return np.ldexp(values, 1 - np.frexp(largest)[1])


def _to_float32(resampled: np.ndarray, values: np.ndarray, path: str) -> np.ndarray:
  """f32 of a rescaled, resampled map [H, W]; DatasetError naming the file when a pixel with a prior would lose it
  (below float32's normal numbers, which XLA flushes to 0): its values [h, w] span more than float32 holds."""
  single = resampled.astype(np.float32)
  if np.any((resampled != 0) & ~(np.abs(single) >= np.finfo(np.float32).tiny)):
    magnitudes = np.abs(values[np.isfinite(values) & (values != 0)])
    raise base.DatasetError(f'depth map {path!r} holds values from {magnitudes.min():.3g} to {magnitudes.max():.3g} '
                            f'(in magnitude), a wider span than float32 holds ({1 / np.finfo(np.float32).tiny:.3g}) '
                            'even rescaled; expected a map whose valid values span less')
  return single


def _check_aspect(values: np.ndarray, path: str, height: int, width: int) -> None:
  """DatasetError naming the file when a map's aspect ratio is not its image's (within one pixel)."""
  h, w = values.shape
  if abs(h * width - height * w) > max(w, width):
    raise base.DatasetError(f'depth map {path!r} is {w} x {h} pixels, not the aspect ratio of its image '
                            f'({width} x {height} as trained); expected a map of the whole image at any size')


def load_maps(dataset: base.Dataset, config) -> np.ndarray:
  """f32 [N, H, W] maps of the dataset's (training) views at its resolution, 0 = no prior; errors name a file."""
  folder = config.depth_prior_dir
  if not os.path.isdir(folder):
    raise base.DatasetNotFoundError(f'Config.depth_prior_dir = {folder!r} is not a folder; expected one depth map '
                                    'per training image (<image stem>.npy or .png)')
  if dataset.image_paths is None:
    raise base.DatasetError(f'Config.depth_prior_dir: the {dataset.name!r} scene keeps no image file names to find '
                            'its depth maps by (a packed scene); train on the scene\'s own folder')
  maps = []
  for image_path in dataset.image_paths:
    path = map_path(folder, image_path)
    values = read_map(path)
    _check_aspect(values, path, dataset.height, dataset.width)
    if not (np.isfinite(values) & (values != 0)).any():
      raise base.DatasetError(f'depth map {path!r} holds no value: every entry is 0 or not finite ("no prior")')
    maps.append(_to_float32(resample(rescaled(values), dataset.height, dataset.width), values, path))
    if not maps[-1].any():
      raise base.DatasetError(f'depth map {path!r}: its valid values cover no pixel at the training size '
                              f'{dataset.width} x {dataset.height}')
  return np.stack(maps)
