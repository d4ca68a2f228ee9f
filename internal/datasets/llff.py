"""LLFF loader: poses_bounds.npy + images_{factor}/, NDC rays, every llffhold-th image for test."""

import os
import warnings

import numpy as np

from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, image_io, random_poses

IMAGE_EXTENSIONS = ('JPG', 'jpg', 'png')
AXIS_FIX = np.array([[0., -1., 0., 0.], [1., 0., 0., 0.], [0., 0., 1., 0.], [0., 0., 0., 1.]])
PROTOCOL_SCENES = ('fern', 'flower', 'fortress', 'horns', 'leaves', 'orchids', 'room', 'trex')  # The paper's 8.

def image_folder(scene_dir: str, factor: int, name: str = 'images') -> tuple:
  """(folder, extra factor): <name>_{factor}/ (<name>/ for 1), else a finer <name>_k/ to downsample by factor/k.

  Building the images from a made-ahead copy of another size (an LLFF scene's images_4/ for factor 8) is said in
  a warning; from the full-size <name>/ (the generated scene's, a capture's own photos) it is the layout's design.
  """
  for k in sorted((k for k in range(1, factor + 1) if factor % k == 0), reverse=True):
    folder = os.path.join(scene_dir, f'{name}_{k}' if k > 1 else name)
    if os.path.isdir(folder):
      if k not in (1, factor):
        warnings.warn(f'{os.path.join(scene_dir, f"{name}_{factor}")!r} does not exist (downsampling factor '
                      f'{factor}); building the images from {folder!r}, downsampled by {factor // k}', stacklevel=2)
      return folder, factor // k
  found = [e for e in base.listing(scene_dir) if e.startswith(name)]
  raise base.DatasetNotFoundError(f'{os.path.join(scene_dir, f"{name}_{factor}" if factor > 1 else name)!r} does '
                                  f'not exist (Config.factor = {factor}); image folders present: {found}')


def image_files(folder: str) -> list:
  """Sorted paths of the JPG/jpg/png files of folder."""
  return [os.path.join(folder, f) for f in base.listing(folder) if f.endswith(IMAGE_EXTENSIONS)]


def read_poses_bounds(scene_dir: str, image_paths=None) -> np.ndarray:
  """[N,17] rows of poses_bounds.npy (3x5 [R|t|hwf] row-major, then near, far), cameras and bounds checked.

  image_paths [N] (the images the rows belong to, in order) name the image of a bad camera; of another count
  they cannot be matched to the rows (the caller refuses that), so only the row is named.
  """
  path = base.require_file(os.path.join(scene_dir, 'poses_bounds.npy'), 'LLFF poses')
  try:
    data = np.load(path)
  except (OSError, ValueError, EOFError) as err:
    raise base.DatasetError(f'cannot read camera file {path!r} (expected a .npy array of shape [N, 17]): '
                            f'{err}') from err
  if data.ndim != 2 or data.shape[1] != 17 or not data.shape[0]:
    raise base.DatasetError(f'{path!r} has shape {data.shape}; expected [N, 17] (3x5 pose + 2 bounds per image)')
  names = [f' ({os.path.basename(p)!r})' for p in image_paths or ()]
  names = names if len(names) == len(data) else [''] * len(data)
  labels = [f'image {i}{name}' for i, name in enumerate(names)]
  base.check_cameras(data[:, :15].reshape(-1, 3, 5), path, labels, 'pose')
  base.check_finite(data[:, 15:17], path, 'the near/far bounds')
  if (data[:, 15:17] <= 0).any():
    raise base.DatasetError(f'{path!r}: the near/far bounds (columns 15, 16) must be positive; found minimum '
                            f'{data[:, 15:17].min()}')
  return data.astype(np.float64)


def process_poses(poses_bounds: np.ndarray) -> tuple:
  """(c2w [N,3,4] OpenGL, recentered, scaled; bounds [N,2] scaled; focal of image 0 at full res)."""
  poses = poses_bounds[:, :15].reshape(-1, 3, 5)
  bounds = poses_bounds[:, 15:17]
  c2w = poses[:, :, :4] @ AXIS_FIX
  scale = 1. / (bounds.min() * .75)
  c2w[:, :, 3] *= scale
  return algebra.recenter_poses(c2w), bounds * scale, poses[0, 2, 4]


def split_ids(split: str, n_images: int, llffhold: int, n_views: int) -> list:
  """Test: i % llffhold == 0. Train: n_views of the rest, evenly spaced with round half to even."""
  if llffhold < 1:
    raise base.DatasetError(f'Config.llffhold = {llffhold}; expected a positive integer')
  if split == 'test':
    return [i for i in range(n_images) if i % llffhold == 0]
  pool = [i for i in range(n_images) if i % llffhold]
  if base.all_views(n_views, len(pool), 'LLFF'):
    return pool
  if n_views > len(pool):
    raise base.DatasetError(f'Config.n_input_views = {n_views} exceeds the {len(pool)} LLFF training views '
                            f'(pool {pool}); Config.n_input_views = 0 selects all of them')
  return [pool[int(round(v))] for v in np.linspace(0, len(pool) - 1, n_views)]


def scene_setup(scene_dir: str, factor: int) -> tuple:
  """(image paths, extra downsampling factor, poses_bounds [N,17]); the counts must agree."""
  folder, extra = image_folder(scene_dir, factor)
  paths = image_files(folder)
  poses_bounds = read_poses_bounds(scene_dir, paths)
  if len(paths) != len(poses_bounds):
    raise base.DatasetError(f'LLFF: {len(paths)} images in {folder!r} but {len(poses_bounds)} poses in '
                            f'{os.path.join(scene_dir, "poses_bounds.npy")!r}; expected one pose per image')
  return paths, extra, poses_bounds


def load_llff(split: str, config, scene_dir: str, name: str) -> base.Dataset:
  """Loads one split of an LLFF scene (NDC rays, near 0, far 1)."""
  factor = base.load_factor(config, split)
  paths, extra, poses_bounds = scene_setup(scene_dir, factor)
  c2w, _, focal = process_poses(poses_bounds)
  ids = base.choose_views(config, split, lambda s: split_ids(s, len(paths), config.llffhold, config.n_input_views),
                          len(paths), f'the LLFF scene {scene_dir!r}')
  images = image_io.load_stack([paths[i] for i in ids],
                               lambda p: image_io.load_rgb(p, extra, config.downsample_mode))
  height, width = images.shape[1:3]
  pixtocam = algebra.focal_pixtocam(focal / factor, height, width)
  space = ray_space(focal / factor, height, width)
  return base.Dataset(images=images, camtoworlds=c2w[ids].astype(np.float32),
                      pixtocams=np.repeat(pixtocam[None], len(ids), 0).astype(np.float32), ids=list(ids),
                      height=height, width=width, near=space.near, far=space.far, masks=None,
                      rays=ndc_rays(c2w[ids], pixtocam, space), split=split, name=name,
                      image_paths=[paths[i] for i in ids], space=space)


def ray_space(focal: float, height: int, width: int) -> RaySpace:
  """LLFF's rays: OpenGL cameras, NDC of the given focal length (pixels), near 0 and far 1."""
  near, far = caster.NDC_NEAR_FAR
  return RaySpace(opengl=True, near=near, far=far, height=height, width=width, ndc_focal=focal)


def ndc_rays(camtoworlds: np.ndarray, pixtocam: np.ndarray, space: RaySpace):
  """Rays [N,H,W,...] of cameras [N,3,4] with one pixtocam [3,3] in space."""
  return caster.image_rays(Cameras(camtoworlds, np.broadcast_to(pixtocam, (len(camtoworlds), 3, 3))), space)


def scene_path(config) -> str:
  """The folder of the scene Config.llff_scan names under Config.data_dir (both checked)."""
  return base.scene_dir(config.data_dir, config.llff_scan, 'llff_scan')


def load_scene(split: str, config) -> base.Dataset:
  """Loads one split of the LLFF scene Config.llff_scan."""
  return load_llff(split, config, scene_path(config), f'llff/{config.llff_scan}')


def scene_render_path(config):
  """Rays [F,H,W,...] (NDC) of the spiral path of the LLFF scene Config.llff_scan."""
  return render_path_rays(config, scene_path(config))


def render_cameras(scene_dir: str, factor: int) -> tuple:
  """(c2w [N,3,4], bounds [N,2], focal, pixtocam [3,3], height, width) of the spiral's frames at 1/factor size."""
  paths, extra, poses_bounds = scene_setup(scene_dir, factor)
  c2w, bounds, focal = process_poses(poses_bounds)
  full_h, full_w = image_io.image_size(paths[0])
  height, width = full_h // extra, full_w // extra
  return c2w, bounds, focal / factor, algebra.focal_pixtocam(focal / factor, height, width), height, width


def render_path_rays(config, scene_dir: str):
  """Rays [F,H,W,...] (NDC) of the LLFF spiral path (Config.render_path_frames frames)."""
  c2w, bounds, focal, pixtocam, height, width = render_cameras(scene_dir, base.render_factor(config))
  path = algebra.spiral_path_llff(c2w, bounds, config.render_path_frames)
  return ndc_rays(path, pixtocam, ray_space(focal, height, width))


def camera_record(config, datasets: dict, scene_dir: str) -> dict:
  """Float64 cameras of an LLFF scene for packed.py: all recentered poses and scaled bounds, per-split views, the
  spiral."""
  record = {'ray_kind': 'llff', 'path_kind': 'spiral_llff', 'arrays': {}}
  c2w, bounds, focal = process_poses(read_poses_bounds(scene_dir))
  for split, data in datasets.items():
    split_focal = focal / base.load_factor(config, split)
    pixtocam = algebra.focal_pixtocam(split_focal, data.height, data.width)
    record['arrays'].update({f'{split}/camtoworlds': c2w[data.ids],
                             f'{split}/pixtocams': np.repeat(pixtocam[None], len(data.ids), 0),
                             f'{split}/focal': np.float64(split_focal)})
  _, _, render_focal, pixtocam, height, width = render_cameras(scene_dir, base.render_factor(config))
  train_pixtocam = record['arrays']['train/pixtocams'][0]
  record['arrays'].update({'cameras/camtoworlds': c2w, 'cameras/bounds': bounds,
                           'cameras/pixtocams': np.repeat(train_pixtocam[None], len(c2w), 0),
                           'render/source': c2w, 'render/bounds': bounds, 'render/pixtocam': pixtocam,
                           'render/focal': np.float64(render_focal), 'cameras/focal_full': np.float64(focal)})
  record['render'] = {'height': height, 'width': width}
  return record


def pack_cameras(config, datasets: dict) -> dict:
  """The pack's camera record of the LLFF scene Config.llff_scan (see camera_record)."""
  return camera_record(config, datasets, scene_path(config))


def random_cameras(dataset: base.Dataset, config, rng: np.random.Generator, scene_dir: str) -> Cameras:
  """RegNeRF's random poses of an LLFF-layout scene, with the pixtocam of the dataset's size."""
  c2w, bounds, focal = process_poses(read_poses_bounds(scene_dir))
  focal /= base.load_factor(config, 'train')
  poses = random_poses.llff_random_poses(c2w, bounds, config.n_random_poses, rng,
                                         not config.regnerf_fix_released_bugs)
  pixtocam = algebra.focal_pixtocam(focal, dataset.height, dataset.width)
  return Cameras(poses, np.broadcast_to(pixtocam, (len(poses), 3, 3)))


def random_pose_cameras(dataset: base.Dataset, config, rng: np.random.Generator) -> Cameras:
  """The random poses of the LLFF scene Config.llff_scan (see random_cameras)."""
  return random_cameras(dataset, config, rng, scene_path(config))
