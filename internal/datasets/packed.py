"""A scene packed into one .npz: both splits, the cameras and the render path, loadable without the data folder.

Images, masks and ground truth are stored exactly as the loader returned them, palette-coded: the distinct
float32 values (sorted) plus uint8/uint16 indices, or raw float32 when there are more than 65536 values. Rays
are not stored: they are regenerated from the float64 cameras by the same functions the loaders use, so
packed and unpacked rays are bitwise equal (pack_scene checks it before writing). `meta` (JSON) records the
source loader, the Config settings that shaped the data (checked on load) and the ray/path kinds.
"""

import dataclasses
import json
import os
import zipfile

import numpy as np

from internal import configs
from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base

VERSION = 1
FIELDS = ('images', 'masks', 'depths', 'object_masks')


def _jsonable(value):
  """Tuples as lists, numpy scalars as Python numbers (JSON round trip)."""
  return json.loads(json.dumps(value, default=lambda x: x.tolist()))


def settings(config) -> dict:
  """{Config field: value} of the settings that shape the data of every loader and of Config.dataset_loader's."""
  names = configs.shaping_settings(configs.ALL_LOADERS) + configs.shaping_settings(config.dataset_loader)
  return {name: _jsonable(getattr(config, name)) for name in names}


# ---------------------------------------------------------------- value coding

def encode(name: str, values: np.ndarray) -> dict:
  """{name/palette f32 [K], name/index uint8|uint16} (exact), or {name: f32} when K > 65536."""
  palette, index = np.unique(values, return_inverse=True)
  if len(palette) > 65536:
    return {name: values}
  dtype = np.uint8 if len(palette) <= 256 else np.uint16
  return {f'{name}/palette': palette, f'{name}/index': index.reshape(values.shape).astype(dtype)}


def decode(arrays, name: str):
  """The array stored by encode under name, or None when absent."""
  if f'{name}/palette' in arrays:
    return arrays[f'{name}/palette'][arrays[f'{name}/index']]
  return arrays[name] if name in arrays else None


# ---------------------------------------------------------------- rays from cameras

def ray_space(kind: str, height: int, width: int, params: dict) -> RaySpace:
  """The RaySpace the loader of ray kind 'dtu' | 'llff' | 'pinhole' sets (dtu, llff, blender.ray_space), from the
  pack's ray parameters."""
  if kind == 'dtu':
    return RaySpace(opengl=False, near=params['near'], far=params['far'], height=height, width=width,
                    plane_z=params['near_origin'])
  if kind == 'llff':
    near, far = caster.NDC_NEAR_FAR
    return RaySpace(opengl=True, near=near, far=far, height=height, width=width, ndc_focal=params['focal'])
  # Packs written before Config.pixel_offset existed hold pixel-centre rays.
  return RaySpace(opengl=True, near=params['near'], far=params['far'], height=height, width=width,
                  pixel_offset=params.get('pixel_offset', .5))


def path_poses(kind: str, source, bounds, n_frames: int) -> np.ndarray:
  """[F,3,4] render-path cameras from the path's source cameras [M,3,4] (and LLFF bounds [M,2])."""
  if kind == 'spiral_dtu':
    return algebra.spiral_path_dtu(source, n_frames)
  if kind == 'spiral_llff':
    return algebra.spiral_path_llff(source, bounds, n_frames)
  return algebra.orbit_path(source, n_frames)


# ---------------------------------------------------------------- pack and load

def pack_arrays(config, datasets: dict, record: dict) -> dict:
  """Every array of the pack ('meta' JSON included) from the loaded splits {split: Dataset}.

  The pack records the settings that shaped the data (`settings`, checked on load); record: the cameras of the
  scene ({'ray_kind', 'path_kind', 'render', 'arrays'}, see dtu.pack_cameras).
  """
  arrays = dict(record['arrays'])
  splits = {}
  for split, data in datasets.items():
    for field in FIELDS:
      if getattr(data, field) is not None:
        arrays.update(encode(f'{split}/{field}', getattr(data, field)))
    splits[split] = {'ids': list(map(int, data.ids)), 'height': data.height, 'width': data.width,
                     'near': float(data.near), 'far': float(data.far), 'name': data.name}
  meta = {'version': VERSION, 'source_loader': config.dataset_loader,
          'settings': settings(config),
          'ray_kind': record['ray_kind'], 'path_kind': record['path_kind'],
          'ray_params': {'near': float(config.near), 'far': float(config.far),
                         'near_origin': float(config.near_origin), 'pixel_offset': float(config.pixel_offset)},
          'render': {**record['render'], 'factor': base.render_factor(config)}, 'splits': splits}
  arrays['meta'] = np.array(json.dumps(meta))
  return arrays


def write_pack(path: str, arrays: dict) -> None:
  """Writes arrays to path (.npz, compressed) through a temporary file, so a failed write leaves nothing."""
  tmp = path + '.partial.npz'
  try:
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
  except BaseException:
    if os.path.exists(tmp):
      os.remove(tmp)
    raise


def read_pack(path: str) -> tuple:
  """(meta dict, arrays {name: np.ndarray}) of a pack; clear errors for a missing or foreign file."""
  if os.path.isdir(path):
    raise base.DatasetError(f"Config.data_dir = {path!r} is a folder; Config.dataset_loader = 'packed' expects the "
                            '.npz file written by python -m tools.pack_scene')
  if not os.path.isfile(path):
    raise base.DatasetNotFoundError(f"Config.data_dir = {path!r} does not exist (Config.dataset_loader = 'packed' "
                                    'expects a file written by python -m tools.pack_scene)')
  try:
    with np.load(path, allow_pickle=False) as f:
      arrays = {k: f[k] for k in f.files}
    meta = json.loads(str(arrays.pop('meta')))
  except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as err:
    raise base.DatasetError(f'Config.data_dir = {path!r} is not a packed scene (expected an .npz written by '
                            f'python -m tools.pack_scene): {err!r}') from err
  if meta.get('version') != VERSION:
    raise base.DatasetError(f'{path!r} is a version {meta.get("version")} pack; this code reads version {VERSION}. '
                            'Pack the scene again.')
  return meta, arrays


def check_settings(config, meta: dict, path: str) -> None:
  """Raises naming the first Config setting that differs from the one the pack was made with."""
  for name, packed in meta['settings'].items():
    current = _jsonable(getattr(config, name))
    if current != packed:
      raise base.DatasetError(f'Config.{name} = {current!r}, but the packed scene {path!r} was made with '
                              f'Config.{name} = {packed!r}; set it to that value or pack the scene again')


def source_loader(path: str) -> str:
  """The loader ('dtu' | 'llff' | 'blender' | 'generated') a pack was made with."""
  return read_pack(path)[0]['source_loader']


def load_scene(split: str, config) -> base.Dataset:
  """One split of the packed scene at Config.data_dir, equal to what the source loader returned."""
  base.check_split(split)
  meta, arrays = read_pack(config.data_dir)
  check_settings(config, meta, config.data_dir)
  info = meta['splits'][split]
  c2w, pixtocams = arrays[f'{split}/camtoworlds'], arrays[f'{split}/pixtocams']
  labels = [f'{split} view {i} (id {view})' for i, view in enumerate(info['ids'])]
  base.check_cameras(c2w, config.data_dir, labels, 'camtoworld')
  base.check_cameras(pixtocams, config.data_dir, labels, 'pixtocam')
  params = {**meta['ray_params'], 'focal': float(arrays.get(f'{split}/focal', 0.))}
  space = ray_space(meta['ray_kind'], info['height'], info['width'], params)
  fields = {field: decode(arrays, f'{split}/{field}') for field in FIELDS}
  return base.Dataset(camtoworlds=c2w.astype(np.float32), pixtocams=pixtocams.astype(np.float32), ids=info['ids'],
                      height=info['height'], width=info['width'], near=info['near'], far=info['far'],
                      rays=caster.image_rays(Cameras(c2w, pixtocams), space), split=split, name=info['name'],
                      space=space, **fields)


def scene_render_path(config):
  """Rays [F,H,W,...] of the packed scene's render path (Config.render_path_frames frames)."""
  meta, arrays = read_pack(config.data_dir)
  check_settings(config, meta, config.data_dir)
  render = meta['render']
  if base.render_factor(config) != render['factor']:
    raise base.DatasetError(f'Config.render_factor = {config.render_factor} (render factor {base.render_factor(config)}) '
                            f'differs from the packed render factor {render["factor"]} of {config.data_dir!r}; '
                            'set Config.render_factor to it or pack the scene again')
  poses = path_poses(meta['path_kind'], arrays['render/source'], arrays.get('render/bounds'),
                     config.render_path_frames)
  params = {**meta['ray_params'], 'focal': float(arrays.get('render/focal', 0.))}
  cameras = Cameras(poses, np.broadcast_to(arrays['render/pixtocam'], (len(poses), 3, 3)))
  return caster.image_rays(cameras, ray_space(meta['ray_kind'], render['height'], render['width'], params))


def rays_equal(a, b) -> bool:
  """Whether two Rays are bitwise equal field by field."""
  return all(np.array_equal(x, y) for x, y in zip(a, b))


def datasets_equal(a: base.Dataset, b: base.Dataset) -> list:
  """Names of the Dataset fields that differ (rays compared bitwise, arrays exactly); where the images were read
  from (image_paths) is not data, and a pack does not keep it."""
  diff = []
  for f in dataclasses.fields(base.Dataset):
    if f.name == 'image_paths':
      continue
    x, y = getattr(a, f.name), getattr(b, f.name)
    same = rays_equal(x, y) if f.name == 'rays' else (
        (x is None and y is None) if x is None or y is None else np.array_equal(np.asarray(x), np.asarray(y)))
    if not same:
      diff.append(f.name)
  return diff
