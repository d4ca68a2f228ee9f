"""The Dataset record, the loader errors and small checks shared by every loader."""

import dataclasses
import os
import zipfile
from typing import List, Optional, Sequence

import numpy as np

from internal.cameras.records import Cameras, RaySpace
from internal.rays import Rays

SPLITS = ('train', 'test')
RELEASED_ALL_VIEWS = 100  # The released *_mipnerf_all configs write n_input_views = 100 for "every view".


class DatasetError(ValueError):
  """Bad or missing input data; the message names the path or Config setting and what was expected."""


class DatasetNotFoundError(DatasetError, FileNotFoundError):
  """A file or folder the loader needs does not exist."""


@dataclasses.dataclass
class Dataset:
  """One split of one scene: images f32 [N,H,W,3], cameras, rays [N,H,W,...] cast from them in its RaySpace (set by
  its loader) and optional masks/depths."""
  images: np.ndarray            # f32 [N,H,W,3] in [0,1].
  camtoworlds: np.ndarray       # f32 [N,3,4].
  pixtocams: np.ndarray         # f32 [N,3,3] (inverse intrinsics at the loaded resolution).
  ids: List[int]                # Original view indices, in load order.
  height: int
  width: int
  near: float
  far: float
  masks: Optional[np.ndarray]   # f32 [N,H,W,3] DTU evaluation masks (test split), else None.
  rays: Rays                    # numpy fields [N,H,W,3] or [N,H,W,1].
  split: str
  name: str
  depths: Optional[np.ndarray] = None        # f32 [N,H,W] exact z-depth (generated scene), 0 = no hit.
  object_masks: Optional[np.ndarray] = None  # f32 [N,H,W] object coverage (generated scene).
  # The image file of each view, in load order (depth priors are named after them); None: a pack keeps none.
  image_paths: Optional[List[str]] = None
  space: Optional[RaySpace] = None        # How its rays follow from its cameras (cameras/caster.py).
  distortion: Optional[np.ndarray] = None  # f32 [N,8] COLMAP's camera parameters (captures), else None: pinholes.

  @property
  def cameras(self) -> Cameras:
    """The cameras its rays were cast from (float32, as kept)."""
    return Cameras(self.camtoworlds, self.pixtocams, self.distortion)


def subset(data: Dataset, positions: Sequence[int]) -> Dataset:
  """The views of data at positions (indices into its views), every per-view field with them."""
  positions = list(positions)
  take = lambda x: None if x is None else x[positions]
  pick = lambda x: None if x is None else [x[p] for p in positions]
  return dataclasses.replace(data, images=data.images[positions], camtoworlds=data.camtoworlds[positions],
                             pixtocams=data.pixtocams[positions], ids=pick(data.ids), masks=take(data.masks),
                             rays=Rays(*[x[positions] for x in data.rays]), depths=take(data.depths),
                             object_masks=take(data.object_masks), image_paths=pick(data.image_paths),
                             distortion=take(data.distortion))


def check_split(split: str) -> None:
  """Raises DatasetError unless split is 'train' or 'test'."""
  if split not in SPLITS:
    raise DatasetError(f'unknown split {split!r}; expected one of {list(SPLITS)}')


def check_choice(setting: str, value, options: Sequence[str], error: type = DatasetError) -> None:
  """Raises error (a ValueError) naming setting, e.g. 'Config.batching', unless value is one of options."""
  if value not in options:
    raise error(f'{setting} = {value!r}; expected one of {list(options)}')


def listing(path: str) -> List[str]:
  """Sorted entries of a folder ([] when it is absent)."""
  return sorted(os.listdir(path)) if os.path.isdir(path) else []


def require_file(path: str, what: str) -> str:
  """Returns path, or raises DatasetNotFoundError naming it."""
  if not os.path.isfile(path):
    raise DatasetNotFoundError(f'{what}: file {path!r} does not exist')
  return path


ARCHIVES = ('.zip', '.tar', '.tar.gz', '.tgz', '.tar.xz', '.7z', '.rar')


def require_data_folder(data_dir: str, holding: str) -> None:
  """Raises, naming Config.data_dir, unless it is a folder: absent, or a file (an archive: unpack it first)."""
  if os.path.isdir(data_dir):
    return
  if not os.path.exists(data_dir):
    raise DatasetNotFoundError(f'Config.data_dir = {data_dir!r} does not exist (expected a folder holding {holding})')
  archive = data_dir.lower().endswith(ARCHIVES) or zipfile.is_zipfile(data_dir)
  unpack = '; it is an archive: unpack it and set Config.data_dir to the unpacked folder' if archive else ''
  raise DatasetError(f'Config.data_dir = {data_dir!r} is a file; expected a folder holding {holding}{unpack}')


def scene_dir(data_dir: str, scene: str, setting: str) -> str:
  """<data_dir>/<scene> after checking both exist (the error lists the scenes found)."""
  require_data_folder(data_dir, 'scenes')
  path = os.path.join(data_dir, scene)
  if not os.path.isdir(path):
    found = [e for e in listing(data_dir) if os.path.isdir(os.path.join(data_dir, e))]
    raise DatasetNotFoundError(f'Config.{setting} = {scene!r}: {path!r} does not exist; '
                               f'{data_dir!r} holds {found}')
  return path


def first_n(pool: Sequence[int], n: int, what: str) -> List[int]:
  """The first n ids of the training pool (n = 0: all of it); raises when n exceeds the pool."""
  if all_views(n, len(pool), what):
    return list(pool)
  if n > len(pool):
    raise DatasetError(f'Config.n_input_views = {n} exceeds the {len(pool)} training views of {what} '
                       f'(pool {list(pool)}); Config.n_input_views = 0 selects all of them')
  return list(pool[:n])


def all_views(n: int, pool_size: int, what: str) -> bool:
  """Whether n_input_views n selects the whole pool: 0, or the released 100 beyond the pool (said in the log)."""
  if n == RELEASED_ALL_VIEWS and n > pool_size:
    print(f'Config.n_input_views = {n} (the released *_all configs\' "every view") exceeds the {pool_size} '
          f'training views of {what}: training on all of them')
    return True
  return n == 0


def present_test_ids(ids: Sequence[int], paths: Sequence[str], allow_missing: bool) -> List[int]:
  """Test ids whose image exists; missing ones raise unless Config.allow_missing_test_views."""
  missing = [p for p in paths if not os.path.isfile(p)]
  if missing and (not allow_missing or len(missing) == len(paths)):
    raise DatasetNotFoundError(f'{len(missing)} of {len(paths)} test images are missing: {missing}. '
                               'Set Config.allow_missing_test_views = True to evaluate on the views present only.')
  return [i for i, p in zip(ids, paths) if os.path.isfile(p)]


def check_finite(values: np.ndarray, path: str, what: str) -> None:
  """Raises DatasetError naming the file when values (e.g. camera poses or bounds) hold NaN or Inf."""
  values = np.asarray(values, np.float64)
  if not np.isfinite(values).all():
    bad = np.argwhere(~np.isfinite(values.reshape(len(values), -1)))[:, 0] if values.ndim else [0]
    raise DatasetError(f'{path!r}: {what} of entries {sorted(set(int(i) for i in bad))[:10]} are not finite '
                       '(NaN or Inf); expected finite numbers')


# A camera's 3x3 part (rotation, or K R of a projection) whose smallest singular value is below this fraction of
# its largest cannot be inverted to rays (a rotation has 1, DTU's projections 3e-4).
SINGULAR_RATIO = 1e-8


def check_cameras(matrices: np.ndarray, path: str, labels: Sequence[str], what: str = 'camera') -> None:
  """Raises DatasetError naming path and labels[i] when camera i of [N,3,K] (K >= 3) holds NaN or Inf or when
  its 3x3 part is singular (e.g. a zero column), so that no ray could be made from it."""
  for matrix, label in zip(np.asarray(matrices, np.float64), labels):
    if not np.isfinite(matrix).all():
      raise DatasetError(f'{path!r}: the {what} of {label} holds NaN or Inf; expected finite numbers')
    values = np.linalg.svd(matrix[:3, :3], compute_uv=False)
    if values[-1] <= SINGULAR_RATIO * values[0]:
      raise DatasetError(f'{path!r}: the {what} of {label} is degenerate: its 3x3 part (the rotation, or '
                         f'K R of a projection) is singular (singular values '
                         f'{np.array2string(values, precision=3)}); expected an invertible one')


def render_factor(config) -> int:
  """The render path's downsampling factor (>= 1): Config.render_factor, else Config.factor."""
  return max(int(config.render_factor or config.factor), 1)


def load_factor(config, split: str) -> int:
  """Total integer downsampling factor (>= 1): Config.factor, times Config.eval_factor for the test split."""
  factor = max(int(config.factor), 1)
  if split == 'test':
    factor *= max(int(getattr(config, 'eval_factor', 1)), 1)
  return factor


VIEW_SETTINGS = {'train': 'train_view_ids', 'test': 'test_view_ids'}


def _explicit_ids(config, split: str, n_images: int, what: str) -> Optional[List[int]]:
  """Config.<split>_view_ids as a list of ids, checked (non-empty, distinct, within 0..n_images - 1), or None."""
  setting = VIEW_SETTINGS[split]
  ids = getattr(config, setting)
  if ids is None:
    return None
  ids = [int(i) for i in ids]
  if not ids:
    raise DatasetError(f'Config.{setting} = []: the {split} split would be empty; give at least one view id '
                       '(or None for the protocol\'s views)')
  bad = [i for i in ids if not 0 <= i < n_images]
  if bad or len(set(ids)) < len(ids):
    raise DatasetError(f'Config.{setting} = {ids}: ' + (f'ids {bad} are outside the {n_images} views of {what} '
                       f'(0..{n_images - 1})' if bad else 'an id repeats'))
  if split == 'train' and config.n_input_views not in (0, len(ids)):
    raise DatasetError(f'Config.{setting} names {len(ids)} views but Config.n_input_views = '
                       f'{config.n_input_views}; set n_input_views to {len(ids)} (it files the run) or 0')
  return ids


def choose_views(config, split: str, defaults, n_images: int, what: str, shared: bool = True) -> List[int]:
  """The view ids of split: Config.train_view_ids / test_view_ids where set (checked), else defaults(split)
  (a callable of the split, so that a protocol's default that does not apply is never computed).

  shared: train and test ids index the same images (n_images of them), so that a view in both is refused; else
  the split's ids index its own n_images.
  """
  if not shared:
    own = _explicit_ids(config, split, n_images, what)
    return own if own is not None else list(defaults(split))
  explicit = {s: _explicit_ids(config, s, n_images, what) for s in VIEW_SETTINGS}
  if all(ids is None for ids in explicit.values()):
    return explicit[split] if explicit[split] is not None else list(defaults(split))
  ids = {s: explicit[s] if explicit[s] is not None else list(defaults(s)) for s in VIEW_SETTINGS}
  both = sorted(set(ids['train']) & set(ids['test']))
  if both:
    raise DatasetError(f'views {both} of {what} are both training views (Config.train_view_ids or the '
                       'protocol\'s) and test views (Config.test_view_ids or the protocol\'s); a test view must '
                       'be held out')
  return ids[split]
