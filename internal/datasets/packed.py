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

from internal.datasets import base, blender, cameras, dtu, image_io, llff, raygen

VERSION = 1
COMMON_SETTINGS = ('factor', 'eval_factor', 'n_input_views', 'downsample_mode')
FIELDS = ('images', 'masks', 'depths', 'object_masks')


def _jsonable(value):
  """Tuples as lists, numpy scalars as Python numbers (JSON round trip)."""
  return json.loads(json.dumps(value, default=lambda x: x.tolist()))


def settings(config, source_settings) -> dict:
  """{Config field: value} of the common settings and those of the source loader that shape the data."""
  return {name: _jsonable(getattr(config, name)) for name in COMMON_SETTINGS + tuple(source_settings)}


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

def make_rays(kind: str, c2w, pixtocam, height: int, width: int, params: dict):
  """Rays [H,W,...] of one camera by ray kind 'dtu' | 'llff' | 'pinhole' (the loaders' functions)."""
  if kind == 'dtu':
    return raygen.dtu_rays(c2w, pixtocam, height, width, params['near'], params['far'], params['near_origin'])
  if kind == 'llff':
    return raygen.llff_rays(c2w, pixtocam, height, width, params['focal'])
  # Packs written before Config.pixel_offset existed hold pixel-centre rays.
  return raygen.pinhole_rays(c2w, pixtocam, height, width, params['near'], params['far'], True,
                             params.get('pixel_offset', .5))


def path_poses(kind: str, source, bounds, n_frames: int) -> np.ndarray:
  """[F,3,4] render-path cameras from the path's source cameras [M,3,4] (and LLFF bounds [M,2])."""
  if kind == 'spiral_dtu':
    return cameras.spiral_path_dtu(source, n_frames)
  if kind == 'spiral_llff':
    return cameras.spiral_path_llff(source, bounds, n_frames)
  return cameras.orbit_path(source, n_frames)


# ---------------------------------------------------------------- cameras of each source loader

def dtu_cameras(config, datasets: dict) -> dict:
  """Float64 cameras of a DTU scan: all normalized poses, per-split views, the spiral's intrinsics."""
  scan_dir, layout, projections = dtu.scan_setup(config)
  record = {'ray_kind': 'dtu', 'path_kind': 'spiral_dtu', 'arrays': {'cameras/projections': projections}}
  for split, data in datasets.items():
    pixtocams, poses = dtu.normalized_cameras(projections, base.load_factor(config, split))
    record['arrays'].update({f'{split}/camtoworlds': poses[data.ids], f'{split}/pixtocams': pixtocams[data.ids]})
  factor = base.render_factor(config)
  pixtocams, poses = dtu.normalized_cameras(projections, factor)
  train_pool, test_ids = dtu.split_ids(config.dtu_split_type, len(projections), config.dtuhold)
  paths = [p for p in dtu.image_paths(scan_dir, layout, train_pool, config.dtu_light_cond) if os.path.isfile(p)]
  if not paths:
    raise base.DatasetNotFoundError(f'DTU render path: no training image found in {scan_dir!r} to size the frames')
  full_h, full_w = image_io.image_size(paths[0])
  train_pixtocams = dtu.normalized_cameras(projections, base.load_factor(config, 'train'))[0]
  record['arrays'].update({'cameras/camtoworlds': poses, 'cameras/pixtocams': train_pixtocams,
                           'render/source': poses, 'render/pixtocam': pixtocams[test_ids].mean(0)})
  record['render'] = {'height': full_h // factor, 'width': full_w // factor}
  return record


def llff_cameras(config, datasets: dict, scene_dir: str) -> dict:
  """Float64 cameras of an LLFF scene: all recentered poses and scaled bounds, per-split views, the spiral."""
  record = {'ray_kind': 'llff', 'path_kind': 'spiral_llff', 'arrays': {}}
  c2w, bounds, focal = llff.process_poses(llff.read_poses_bounds(scene_dir))
  for split, data in datasets.items():
    split_focal = focal / base.load_factor(config, split)
    pixtocam = cameras.focal_pixtocam(split_focal, data.height, data.width)
    record['arrays'].update({f'{split}/camtoworlds': c2w[data.ids],
                             f'{split}/pixtocams': np.repeat(pixtocam[None], len(data.ids), 0),
                             f'{split}/focal': np.float64(split_focal)})
  factor = base.render_factor(config)
  paths, extra, _ = llff.scene_setup(scene_dir, factor)
  full_h, full_w = image_io.image_size(paths[0])
  height, width = full_h // extra, full_w // extra
  pixtocam = cameras.focal_pixtocam(focal / factor, height, width)
  train_pixtocam = record['arrays']['train/pixtocams'][0]
  record['arrays'].update({'cameras/camtoworlds': c2w, 'cameras/bounds': bounds,
                           'cameras/pixtocams': np.repeat(train_pixtocam[None], len(c2w), 0),
                           'render/source': c2w, 'render/bounds': bounds, 'render/pixtocam': pixtocam,
                           'render/focal': np.float64(focal / factor), 'cameras/focal_full': np.float64(focal)})
  record['render'] = {'height': height, 'width': width}
  return record


def blender_cameras(config, datasets: dict, scene_dir: str) -> dict:
  """Float64 cameras of a Blender-layout scene: per-split frames, the test frames the orbit is built from."""
  record = {'ray_kind': 'pinhole', 'path_kind': 'orbit', 'arrays': {}}
  for split, data in datasets.items():
    meta = blender.read_transforms(scene_dir, split)
    focal = .5 * data.width / np.tan(.5 * float(meta['camera_angle_x']))
    pixtocam = cameras.focal_pixtocam(focal, data.height, data.width)
    c2w = np.array([meta['frames'][i]['transform_matrix'] for i in data.ids], np.float64)[:, :3, :4]
    record['arrays'].update({f'{split}/camtoworlds': c2w,
                             f'{split}/pixtocams': np.repeat(pixtocam[None], len(data.ids), 0)})
  poses, pixtocam, height, width = blender.render_cameras(scene_dir, base.render_factor(config))
  train_pixtocam = record['arrays']['train/pixtocams'][0]
  record['arrays'].update({'cameras/camtoworlds': poses,
                           'cameras/pixtocams': np.repeat(train_pixtocam[None], len(poses), 0),
                           'render/source': poses, 'render/pixtocam': pixtocam})
  record['render'] = {'height': height, 'width': width}
  return record


# ---------------------------------------------------------------- pack and load

def pack_arrays(config, datasets: dict, source_settings, record: dict) -> dict:
  """Every array of the pack ('meta' JSON included) from the loaded splits {split: Dataset}.

  source_settings: the Config fields besides COMMON_SETTINGS that shaped the data (checked on load); record:
  the cameras of the scene ({'ray_kind', 'path_kind', 'render', 'arrays'}, see dtu_cameras).
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
          'settings': settings(config, source_settings),
          'ray_kind': record['ray_kind'], 'path_kind': record['path_kind'],
          'ray_params': {'near': float(config.near), 'far': float(config.far),
                         'near_origin': float(config.near_origin), 'pixel_offset': float(config.pixel_offset)},
          'render': {**record['render'], 'factor': base.render_factor(config)}, 'splits': splits}
  arrays['meta'] = np.array(json.dumps(meta))
  return arrays


def write_pack(path: str, arrays: dict) -> None:
  """Writes arrays to path (.npz, compressed) through a temporary file, so a failed write leaves nothing."""
  tmp = path + '.partial.npz'
  np.savez_compressed(tmp, **arrays)
  os.replace(tmp, path)


def read_pack(path: str) -> tuple:
  """(meta dict, arrays {name: np.ndarray}) of a pack; clear errors for a missing or foreign file."""
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


def load_packed(split: str, config) -> base.Dataset:
  """One split of the packed scene at Config.data_dir, equal to what the source loader returned."""
  base.check_split(split)
  meta, arrays = read_pack(config.data_dir)
  check_settings(config, meta, config.data_dir)
  info = meta['splits'][split]
  c2w, pixtocams = arrays[f'{split}/camtoworlds'], arrays[f'{split}/pixtocams']
  params = {**meta['ray_params'], 'focal': float(arrays.get(f'{split}/focal', 0.))}
  rays = raygen.stack_rays((make_rays(meta['ray_kind'], c2w[i], pixtocams[i], info['height'], info['width'], params)
                            for i in range(len(c2w))), len(c2w))
  fields = {field: decode(arrays, f'{split}/{field}') for field in FIELDS}
  return base.Dataset(camtoworlds=c2w.astype(np.float32), pixtocams=pixtocams.astype(np.float32), ids=info['ids'],
                      height=info['height'], width=info['width'], near=info['near'], far=info['far'], rays=rays,
                      split=split, name=info['name'], **fields)


def render_path_rays(config):
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
  return raygen.stack_rays((make_rays(meta['ray_kind'], p, arrays['render/pixtocam'], render['height'],
                                      render['width'], params) for p in poses), len(poses))


def rays_equal(a, b) -> bool:
  """Whether two Rays are bitwise equal field by field."""
  return all(np.array_equal(x, y) for x, y in zip(a, b))


def datasets_equal(a: base.Dataset, b: base.Dataset) -> list:
  """Names of the Dataset fields that differ (rays compared bitwise, arrays exactly)."""
  diff = []
  for f in dataclasses.fields(base.Dataset):
    x, y = getattr(a, f.name), getattr(b, f.name)
    same = rays_equal(x, y) if f.name == 'rays' else (
        (x is None and y is None) if x is None or y is None else np.array_equal(np.asarray(x), np.asarray(y)))
    if not same:
      diff.append(f.name)
  return diff
