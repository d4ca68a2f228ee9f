"""Blender (NeRF-synthetic) loader: transforms_{train,test}.json + RGBA PNGs, white compositing."""

import json
import os

import numpy as np

from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, image_io

DIETNERF_IDS = (26, 86, 2, 55, 75, 93, 16, 73)
SPLIT_MODES = ('dietnerf', 'first_n')
# (Config field, its allowed values) of this loader's own settings, checked before any work.
SETTING_CHOICES = (('blender_split', SPLIT_MODES),)
TEST_STRIDE = 8  # DietNeRF/FreeNeRF evaluate on test frames [::8] (25 views).
PROTOCOL_SCENES = ('chair', 'drums', 'ficus', 'hotdog', 'lego', 'materials', 'mic', 'ship')  # NeRF-synthetic's 8.

def read_transforms(scene_dir: str, split: str) -> dict:
  """The parsed transforms_{split}.json (camera_angle_x and frames[file_path, transform_matrix])."""
  path = base.require_file(os.path.join(scene_dir, f'transforms_{split}.json'), 'Blender cameras')
  try:
    with open(path) as f:
      meta = json.load(f)
    float(meta['camera_angle_x'])
    for frame in meta['frames']:
      if np.shape(frame['transform_matrix']) != (4, 4):
        raise ValueError(f'frame {frame.get("file_path")} has a transform_matrix that is not 4x4')
    matrices = np.array([frame['transform_matrix'] for frame in meta['frames']], np.float64)
  except (OSError, ValueError, KeyError, TypeError) as err:
    raise base.DatasetError(f'cannot read camera file {path!r} (expected JSON with camera_angle_x and frames of '
                            f'file_path + 4x4 transform_matrix): {err!r}') from err
  labels = [f'frame {i} ({frame.get("file_path")!r})' for i, frame in enumerate(meta['frames'])]
  base.check_cameras(matrices, path, labels, 'transform_matrix')
  return meta


def frame_ids(split: str, n_frames: int, mode: str, n_views: int, test_stride: int) -> list:
  """Frame positions of the split: DietNeRF ids or the first n (train); every test_stride-th frame (test)."""
  base.check_choice('Config.blender_split', mode, SPLIT_MODES)
  if split == 'test':
    return list(range(0, n_frames, test_stride))
  if mode == 'dietnerf' and max(DIETNERF_IDS) >= n_frames:
    raise base.DatasetError(f"Config.blender_split = 'dietnerf' needs train frames {list(DIETNERF_IDS)}; the "
                            f"train json has {n_frames} frames (use blender_split = 'first_n')")
  pool = list(DIETNERF_IDS) if mode == 'dietnerf' else list(range(n_frames))
  return base.first_n(pool, n_views, f'the Blender {mode} split')


def frame_path(scene_dir: str, frame: dict) -> str:
  """Image path of a frame: <scene>/<file_path>.png."""
  path = os.path.join(scene_dir, frame['file_path'])
  return path if path.endswith('.png') else path + '.png'


def composite(rgba: np.ndarray, white_background: bool) -> np.ndarray:
  """[...,4] RGBA -> [...,3] RGB over white (rgb*a + 1-a), or the raw rgb when not white_background."""
  if white_background:
    return rgba[..., :3] * rgba[..., 3:] + (1. - rgba[..., 3:])
  return rgba[..., :3]


def ray_space(config, height: int, width: int) -> RaySpace:
  """The rays of a Blender-layout scene: OpenGL cameras, through pixels + Config.pixel_offset, Config's near and
  far."""
  return RaySpace(opengl=True, near=config.near, far=config.far, height=height, width=width,
                  pixel_offset=config.pixel_offset)


def frame_rays(config, camtoworlds, pixtocam, height: int, width: int):
  """Rays [N,H,W,...] of OpenGL cameras [N,3,4] with one pixtocam [3,3] (ray_space)."""
  cameras = Cameras(camtoworlds, np.broadcast_to(pixtocam, (len(camtoworlds), 3, 3)))
  return caster.image_rays(cameras, ray_space(config, height, width))


def load_blender(split: str, config, scene_dir: str, name: str, mode: str, test_stride: int) -> base.Dataset:
  """Loads one split of a Blender-layout scene (OpenGL cameras, near/far from Config)."""
  meta = read_transforms(scene_dir, split)
  ids = base.choose_views(config, split, lambda s: frame_ids(s, len(meta['frames']), mode, config.n_input_views,
                                                             test_stride),
                          len(meta['frames']), f'{os.path.join(scene_dir, f"transforms_{split}.json")!r}',
                          shared=False)
  paths = [frame_path(scene_dir, meta['frames'][i]) for i in ids]
  if split == 'test':
    ids = base.present_test_ids(ids, paths, config.allow_missing_test_views)
    paths = [frame_path(scene_dir, meta['frames'][i]) for i in ids]
  factor = base.load_factor(config, split)
  images = image_io.load_stack(paths, lambda p: composite(image_io.load_rgba(p, factor, config.downsample_mode),
                                                         config.white_background))
  height, width = images.shape[1:3]
  focal = .5 * width / np.tan(.5 * float(meta['camera_angle_x']))
  pixtocam = algebra.focal_pixtocam(focal, height, width)
  c2w = np.array([meta['frames'][i]['transform_matrix'] for i in ids], np.float64)[:, :3, :4]
  return base.Dataset(images=images.astype(np.float32), camtoworlds=c2w.astype(np.float32),
                      pixtocams=np.repeat(pixtocam[None], len(ids), 0).astype(np.float32), ids=list(ids),
                      height=height, width=width, near=config.near, far=config.far, masks=None,
                      rays=frame_rays(config, c2w, pixtocam, height, width), split=split, name=name,
                      image_paths=paths, space=ray_space(config, height, width))


def render_cameras(scene_dir: str, factor: int):
  """(test camera-to-worlds [N,3,4] f64, pixtocam [3,3], height, width) of render frames at 1/factor size."""
  meta = read_transforms(scene_dir, 'test')
  present = [p for p in (frame_path(scene_dir, f) for f in meta['frames']) if os.path.isfile(p)]
  if not present:
    raise base.DatasetNotFoundError(f'Blender render path: no test image of {scene_dir!r} exists to size the frames')
  full_h, full_w = image_io.image_size(present[0])
  height, width = full_h // factor, full_w // factor
  pixtocam = algebra.focal_pixtocam(.5 * width / np.tan(.5 * float(meta['camera_angle_x'])), height, width)
  poses = np.array([f['transform_matrix'] for f in meta['frames']], np.float64)[:, :3, :4]
  return poses, pixtocam, height, width


def scene_path(config) -> str:
  """The folder of the scene Config.blender_scene names under Config.data_dir (both checked)."""
  return base.scene_dir(config.data_dir, config.blender_scene, 'blender_scene')


def load_scene(split: str, config) -> base.Dataset:
  """Loads one split of the Blender scene Config.blender_scene (test: every TEST_STRIDE-th frame)."""
  return load_blender(split, config, scene_path(config), f'blender/{config.blender_scene}', config.blender_split,
                      TEST_STRIDE)


MESH_BOX = ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))  # Holds every object of the Blender scenes.


def mesh_bounds(config) -> np.ndarray:
  """[2, 3] the region to mesh: MESH_BOX, whatever the scene."""
  del config  # The same for every scene.
  return np.array(MESH_BOX)


def scene_render_path(config):
  """Rays [F,H,W,...] of the orbit path of the Blender scene Config.blender_scene."""
  return render_path_rays(config, scene_path(config))


def render_path_rays(config, scene_dir: str):
  """Rays [F,H,W,...] of an orbit at the test cameras' mean radius and height, facing the origin."""
  poses, pixtocam, height, width = render_cameras(scene_dir, base.render_factor(config))
  return frame_rays(config, algebra.orbit_path(poses, config.render_path_frames), pixtocam, height, width)


def camera_record(config, datasets: dict, scene_dir: str) -> dict:
  """Float64 cameras of a Blender-layout scene for packed.py: per-split frames, the test frames the orbit is built
  from."""
  record = {'ray_kind': 'pinhole', 'path_kind': 'orbit', 'arrays': {}}
  for split, data in datasets.items():
    meta = read_transforms(scene_dir, split)
    focal = .5 * data.width / np.tan(.5 * float(meta['camera_angle_x']))
    pixtocam = algebra.focal_pixtocam(focal, data.height, data.width)
    c2w = np.array([meta['frames'][i]['transform_matrix'] for i in data.ids], np.float64)[:, :3, :4]
    record['arrays'].update({f'{split}/camtoworlds': c2w,
                             f'{split}/pixtocams': np.repeat(pixtocam[None], len(data.ids), 0)})
  poses, pixtocam, height, width = render_cameras(scene_dir, base.render_factor(config))
  train_pixtocam = record['arrays']['train/pixtocams'][0]
  record['arrays'].update({'cameras/camtoworlds': poses,
                           'cameras/pixtocams': np.repeat(train_pixtocam[None], len(poses), 0),
                           'render/source': poses, 'render/pixtocam': pixtocam})
  record['render'] = {'height': height, 'width': width}
  return record


def pack_cameras(config, datasets: dict) -> dict:
  """The pack's camera record of the Blender scene Config.blender_scene (see camera_record)."""
  return camera_record(config, datasets, scene_path(config))
