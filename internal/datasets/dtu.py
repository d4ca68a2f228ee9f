"""DTU loader: RegNeRF layout (Rectified + cal18 + idrmasks) or IDR/NeuS layout (cameras_sphere.npz)."""

import os
import re
import zipfile

import numpy as np

from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, image_io, random_poses

TRAIN_IDS = (25, 22, 28, 40, 44, 48, 0, 8, 13)
EXCLUDED_IDS = (3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 36, 37, 38, 39)
TEST_IDS = (1, 2, 9, 10, 11, 12, 14, 15, 23, 24, 26, 27, 29, 30, 31, 32, 33, 34, 35, 41, 42, 43, 45, 46, 47)
IDR_MASK_SCANS = (40, 55, 63, 110, 114)  # idrmasks keeps these scans' masks in scanN/mask/.
LAYOUTS = ('auto', 'regnerf', 'idr')
# (Config field, its allowed values) of this loader's own settings, checked before any work.
SETTING_CHOICES = (('dtu_layout', LAYOUTS),)
SPLIT_TYPES = ('pixelnerf', 'all', 'dtuhold', 'depth_eval')  # 'depth_eval' (dtu_mipnerf_all.gin) = 'dtuhold'.
# The 15 test scans of pixelNeRF's protocol, which the paper's DTU means cover.
PROTOCOL_SCENES = tuple(f'scan{i}' for i in (8, 21, 30, 31, 34, 38, 40, 41, 45, 55, 63, 82, 103, 110, 114))

def split_ids(split_type: str, n_cameras: int, dtuhold: int) -> tuple:
  """(train pool, test ids) of the DTU split type over n_cameras views ('dtuhold': test = ids % dtuhold == 0)."""
  base.check_choice('Config.dtu_split_type', split_type, SPLIT_TYPES)
  if split_type == 'pixelnerf':
    if n_cameras <= max(TEST_IDS + TRAIN_IDS):
      raise base.DatasetError(f'the pixelnerf DTU split needs 49 cameras; got {n_cameras} '
                              '(Config.dtu_max_images or the camera files)')
    return list(TRAIN_IDS), list(TEST_IDS)
  if split_type == 'all':
    return list(range(n_cameras)), list(range(n_cameras))
  if dtuhold < 1:
    raise base.DatasetError(f'Config.dtuhold = {dtuhold}; expected a positive integer')
  return [i for i in range(n_cameras) if i % dtuhold], [i for i in range(n_cameras) if i % dtuhold == 0]


def scan_number(scan: str) -> int:
  """24 for 'scan24' or 'dtu_scan24'; raises when the name ends without digits."""
  match = re.search(r'(\d+)$', scan)
  if not match:
    raise base.DatasetError(f'Config.dtu_scan = {scan!r}; expected a name ending in the scan number, e.g. scan24')
  return int(match.group(1))


def detect_layout(scan_dir: str, layout: str) -> str:
  """'idr' when cameras_sphere.npz is present, 'regnerf' when rect_*.png images are; layout forces it."""
  base.check_choice('Config.dtu_layout', layout, LAYOUTS)
  if layout != 'auto':
    return layout
  if os.path.isfile(os.path.join(scan_dir, 'cameras_sphere.npz')):
    return 'idr'
  if any(name.startswith('rect_') for name in base.listing(scan_dir)):
    return 'regnerf'
  raise base.DatasetError(f'cannot tell the DTU layout of {scan_dir!r}: expected cameras_sphere.npz + image(s)/ '
                          f'(IDR) or rect_XXX_L_r5000.png images (RegNeRF); found {base.listing(scan_dir)[:10]}')


def calibration_dir(scan_dir: str) -> str:
  """<scan_dir>/../../Calibration/cal18, where RegNeRF's layout keeps pos_XXX.txt."""
  return os.path.join(scan_dir, '..', '..', 'Calibration', 'cal18')


def read_projection_txt(path: str, camera: int) -> np.ndarray:
  """[3,4] projection matrix of the camera (0-based view id) from a cal18 pos_XXX.txt file."""
  base.require_file(path, 'DTU camera (RegNeRF layout expects <data_dir>/<scan>/../../Calibration/cal18)')
  try:
    proj = np.loadtxt(path, dtype=np.float64)
  except ValueError as err:
    raise base.DatasetError(f'cannot read camera file {path!r} (expected a 3x4 matrix of numbers): {err}') from err
  if proj.shape != (3, 4):
    raise base.DatasetError(f'camera file {path!r} holds shape {proj.shape}; expected a 3x4 projection matrix')
  base.check_cameras(proj[None], path, [f'camera {camera}'], 'projection matrix')
  return proj


def regnerf_projections(scan_dir: str, n_cameras: int) -> np.ndarray:
  """[n,3,4] projections pos_001..pos_n (view i is pos_{i+1:03d}.txt)."""
  folder = calibration_dir(scan_dir)
  return np.stack([read_projection_txt(os.path.join(folder, f'pos_{i + 1:03d}.txt'), i) for i in range(n_cameras)])


def idr_projections(scan_dir: str, n_cameras: int) -> np.ndarray:
  """[n,3,4] projections world_mat_i[:3] of cameras_sphere.npz (at most n_cameras)."""
  path = base.require_file(os.path.join(scan_dir, 'cameras_sphere.npz'), 'DTU cameras (IDR layout)')
  try:
    with np.load(path) as cams:
      count = min(n_cameras, sum(1 for k in cams.files if re.fullmatch(r'world_mat_\d+', k)))
      mats = [np.asarray(cams[f'world_mat_{i}'], np.float64) for i in range(count)]
  except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
    raise base.DatasetError(f'cannot read camera file {path!r} (expected an npz with world_mat_0.. '
                            f'world_mat_{n_cameras - 1}, each 4x4 = K[R|t]): {err}') from err
  if not mats or any(m.shape not in ((4, 4), (3, 4)) for m in mats):
    raise base.DatasetError(f'camera file {path!r}: expected world_mat_i arrays of shape 4x4 or 3x4')
  projections = np.stack([m[:3, :4] for m in mats])
  base.check_cameras(projections, path, [f'camera {i} (world_mat_{i})' for i in range(count)], 'projection')
  return projections


def idr_image_dir(scan_dir: str) -> str:
  """The IDR/NeuS image folder: image/ or images/."""
  for name in ('image', 'images'):
    if os.path.isdir(os.path.join(scan_dir, name)):
      return os.path.join(scan_dir, name)
  raise base.DatasetNotFoundError(f'DTU (IDR layout): neither {scan_dir}/image nor {scan_dir}/images exists; '
                                  f'{scan_dir!r} holds {base.listing(scan_dir)}')


def numbered_files(folder: str) -> dict:
  """{index: path} of files in folder whose stem is a number (000.png, 000000.png)."""
  out = {}
  for name in base.listing(folder):
    stem = os.path.splitext(name)[0]
    if stem.isdigit():
      out[int(stem)] = os.path.join(folder, name)
  return out


def image_paths(scan_dir: str, layout: str, ids, light: int) -> list:
  """Image path per 0-based view id (existing or not) in the given layout."""
  if layout == 'idr':
    folder = idr_image_dir(scan_dir)
    found = numbered_files(folder)
    return [found.get(i, os.path.join(folder, f'{i:06d}.png')) for i in ids]
  names = [f'rect_{i + 1:03d}_max.png' if light >= 7 else
           f'rect_{i + 1:03d}_{light}_r{5000 if i < 49 else 7000}.png' for i in ids]
  return [os.path.join(scan_dir, name) for name in names]


def mask_folders(mask_path: str, scan: str) -> list:
  """Candidate mask folders of a scan under Config.dtu_mask_path, most likely first.

  idrmasks keeps <path>/scanN/NNN.png (scans 40, 55, 63, 110, 114: <path>/scanN/mask/NNN.png); a folder of
  IDR/NeuS scans keeps <path>/<scan>/mask/NNN.png.
  """
  number = scan_number(scan)
  names = [f'scan{number}'] + ([scan] if scan != f'scan{number}' else [])
  subdirs = ('mask', '') if number in IDR_MASK_SCANS else ('', 'mask')
  return [os.path.join(mask_path, name, sub) if sub else os.path.join(mask_path, name)
          for name in names for sub in subdirs]


def mask_paths(config, scan_dir: str, layout: str, ids) -> list:
  """Mask path per view id: the scan's own mask/ (empty Config.dtu_mask_path, IDR layout), else the first
  candidate folder under Config.dtu_mask_path that holds every mask (a missing one raises listing the folders)."""
  if not config.dtu_mask_path:
    if layout != 'idr':
      raise base.DatasetError('Config.dtu_mask_path is empty; DTU (RegNeRF layout) test views need the idrmasks '
                              'folder (<dtu_mask_path>/scanN/NNN.png)')
    return [os.path.join(scan_dir, 'mask', f'{i:03d}.png') for i in ids]
  folders = mask_folders(config.dtu_mask_path, config.dtu_scan)
  for folder in folders:
    paths = [os.path.join(folder, f'{i:03d}.png') for i in ids]
    if all(os.path.isfile(p) for p in paths):
      return paths
  raise base.DatasetNotFoundError(
      f'DTU masks of test views {list(ids)} (NNN.png) are not all present in any of {folders} '
      f'(Config.dtu_mask_path = {config.dtu_mask_path!r}, Config.dtu_scan = {config.dtu_scan!r}); set '
      "Config.dtu_mask_path to the idrmasks folder, or to '' to use the IDR scan's own mask/ folder")


def load_masks(paths, factor: int, mode: str) -> np.ndarray:
  """[N,H,W,3] f32 binarised (== 255) and downsampled masks; a missing file raises naming it."""
  for path in paths:
    base.require_file(path, "DTU mask of a test view (Config.dtu_mask_path = '' reads the IDR scan's mask/)")
  return image_io.load_stack(paths, lambda p: image_io.load_binary_mask(p, factor, mode))


def normalized_cameras(projections: np.ndarray, factor: int) -> tuple:
  """(pixtocams [N,3,3], camtoworlds [N,3,4]) from P [N,3,4]: decompose, recenter, rescale (OpenCV axes)."""
  decomposed = [algebra.projection_to_camtoworld(p) for p in projections]
  intrinsics = np.stack([algebra.scale_intrinsics(k, factor) for k, _ in decomposed])
  poses = algebra.rescale_poses(algebra.recenter_poses(np.stack([c2w for _, c2w in decomposed])))
  return np.linalg.inv(intrinsics), poses


def scan_setup(config) -> tuple:
  """(scan_dir, layout, projections [N,3,4]) of Config.data_dir/Config.dtu_scan."""
  scan_dir = base.scene_dir(config.data_dir, config.dtu_scan, 'dtu_scan')
  layout = detect_layout(scan_dir, config.dtu_layout)
  read = idr_projections if layout == 'idr' else regnerf_projections
  return scan_dir, layout, read(scan_dir, config.dtu_max_images)


def view_ids(config, split: str, scan_dir: str, layout: str, n_cameras: int) -> tuple:
  """(ids, image paths) of the split: Config.<split>_view_ids, else the first n train ids or the test ids, those
  present on disk."""
  train_pool, test_ids = split_ids(config.dtu_split_type, n_cameras, config.dtuhold)
  defaults = lambda s: (base.first_n(train_pool, config.n_input_views, f'DTU {config.dtu_split_type} split')
                        if s == 'train' else test_ids)
  chosen = base.choose_views(config, split, defaults, n_cameras, f'DTU scan {scan_dir!r}')
  if split == 'train':
    ids = chosen
    paths = image_paths(scan_dir, layout, ids, config.dtu_light_cond)
    for path in paths:
      base.require_file(path, 'DTU training image')
    return ids, paths
  paths = image_paths(scan_dir, layout, chosen, config.dtu_light_cond)
  ids = base.present_test_ids(chosen, paths, config.allow_missing_test_views)
  return ids, [p for i, p in zip(chosen, paths) if i in ids]


def load_scene(split: str, config) -> base.Dataset:
  """Loads one split of a DTU scan as a Dataset (OpenCV cameras, origins on z = Config.near_origin)."""
  scan_dir, layout, projections = scan_setup(config)
  factor = base.load_factor(config, split)
  ids, paths = view_ids(config, split, scan_dir, layout, len(projections))
  pixtocams, poses = normalized_cameras(projections, factor)
  masks = None
  if split == 'test':
    masks = load_masks(mask_paths(config, scan_dir, layout, ids), factor, config.downsample_mode)
  images = image_io.load_stack(paths, lambda p: image_io.load_rgb(p, factor, config.downsample_mode))
  space = ray_space(config, *images.shape[1:3])
  rays = caster.image_rays(Cameras(poses[ids], pixtocams[ids]), space)
  return base.Dataset(images=images, camtoworlds=poses[ids].astype(np.float32),
                      pixtocams=pixtocams[ids].astype(np.float32), ids=list(ids), height=space.height,
                      width=space.width, near=config.near, far=config.far, masks=masks, rays=rays, split=split,
                      name=f'dtu/{config.dtu_scan}', image_paths=list(paths), space=space)


def ray_space(config, height: int, width: int) -> RaySpace:
  """DTU's rays: OpenCV cameras, Config's near and far, origins on the plane z = Config.near_origin."""
  return RaySpace(opengl=False, near=config.near, far=config.far, height=height, width=width,
                  plane_z=config.near_origin)


def mask_region(test_set: base.Dataset):
  """[2, 3] the object-mask region of DTU's test views: the intersection over the views of the box around each
  view's mask rays from near to far (a loose box around the visual hull; it holds the object); None when every
  mask is empty."""
  boxes = []
  for view in range(len(test_set.ids)):
    inside = test_set.masks[view, ..., 0] > .5
    if inside.any():
      rays = [getattr(test_set.rays, name)[view][inside] for name in ('origins', 'directions', 'near', 'far')]
      ends = np.concatenate([rays[0] + rays[1] * rays[2], rays[0] + rays[1] * rays[3]])
      boxes.append([ends.min(0), ends.max(0)])
  if not boxes:
    return None
  boxes = np.array(boxes)
  return np.stack([boxes[:, 0].max(0), boxes[:, 1].min(0)])


def mesh_bounds(config):
  """[2, 3] the region to mesh: the mask_region of the scan's test views (None: their masks are empty)."""
  return mask_region(load_scene('test', config))


def render_cameras(config) -> tuple:
  """(all normalized poses [N,3,4], mean test pixtocam [3,3], height, width) of the spiral's frames."""
  scan_dir, layout, projections = scan_setup(config)
  factor = base.render_factor(config)
  train_pool, test_ids = split_ids(config.dtu_split_type, len(projections), config.dtuhold)
  paths = [p for p in image_paths(scan_dir, layout, train_pool, config.dtu_light_cond) if os.path.isfile(p)]
  if not paths:
    raise base.DatasetNotFoundError(f'DTU render path: no training image found in {scan_dir!r} to size the frames')
  full_h, full_w = image_io.image_size(paths[0])
  pixtocams, poses = normalized_cameras(projections, factor)
  return poses, pixtocams[test_ids].mean(0), full_h // factor, full_w // factor


def scene_render_path(config):
  """Rays [F,H,W,...] of the DTU spiral over all cameras, with the mean test intrinsics."""
  poses, pixtocam, height, width = render_cameras(config)
  path = algebra.spiral_path_dtu(poses, config.render_path_frames)
  cameras = Cameras(path, np.broadcast_to(pixtocam, (len(path), 3, 3)))
  return caster.image_rays(cameras, ray_space(config, height, width))


def pack_cameras(config, datasets: dict) -> dict:
  """Float64 cameras of a DTU scan for packed.py: all normalized poses, per-split views, the spiral's intrinsics."""
  _, _, projections = scan_setup(config)
  record = {'ray_kind': 'dtu', 'path_kind': 'spiral_dtu', 'arrays': {'cameras/projections': projections}}
  for split, data in datasets.items():
    pixtocams, poses = normalized_cameras(projections, base.load_factor(config, split))
    record['arrays'].update({f'{split}/camtoworlds': poses[data.ids], f'{split}/pixtocams': pixtocams[data.ids]})
  poses, pixtocam, height, width = render_cameras(config)
  train_pixtocams = normalized_cameras(projections, base.load_factor(config, 'train'))[0]
  record['arrays'].update({'cameras/camtoworlds': poses, 'cameras/pixtocams': train_pixtocams,
                           'render/source': poses, 'render/pixtocam': pixtocam})
  record['render'] = {'height': height, 'width': width}
  return record


def random_pose_cameras(dataset: base.Dataset, config, rng: np.random.Generator) -> Cameras:
  """RegNeRF's random poses [n] in the box of all cameras (at the training factor), with their mean pixtocam."""
  del dataset  # Every camera of the scan, at the training factor.
  _, _, projections = scan_setup(config)
  pixtocams, poses = normalized_cameras(projections, base.load_factor(config, 'train'))
  found = random_poses.dtu_random_poses(poses, config.n_random_poses, rng, config.random_pose_radius,
                                        config.random_pose_focusptjitter)
  return Cameras(found, np.broadcast_to(pixtocams.mean(0), (len(found), 3, 3)))
