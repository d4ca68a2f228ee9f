"""Captures: a user's photos with their COLMAP sparse model -> few-view training and held-out test views.

A capture folder holds the images as COLMAP saw them (`Config.capture_images`, optionally with downsampled copies
`<capture_images>_<k>/` of the same names, as LLFF's images_4/) and the model (`Config.capture_model`, binary or
text). Any image size trains: where 'area' downsampling needs sides divisible by the factor, the last rows and
columns that fill no block are cropped (said in one warning), which keeps the cameras exact. Every image may have
its own camera; radial and tangential distortion is inverted per pixel (distortion.py). An image's id is its position in the file-name order of the registered images.

Two rigs (`Config.capture_rig`; 'auto' looks at the spread of the viewing directions):
- inward (an object seen over an arc): world-space rays in a frame centred on the point nearest to every optical
  axis, scaled so that the median camera is 1 unit from it, z up (the cameras' mean up); near and far from the
  depths of the sparse points each image sees (LLFF's 0.1 / 99.9 percentiles, the extremes over the images); the
  render path orbits the centre over the captured arc and back.
- forward (every camera looks the same way): LLFF's pipeline, NDC rays and its spiral path.

Views (the documented rule): the images ordered along the arc (by azimuth about the up axis through the centre,
starting after the widest gap; forward captures in name order), every `Config.llffhold`-th of that order from the
first is a test view, and the `Config.n_input_views` training views are spread evenly over the rest, both ends
included. `Config.train_view_ids` / `Config.test_view_ids` choose them by id instead.
"""

import dataclasses
import os
import warnings
from typing import Dict, List

import numpy as np

from internal.cameras import algebra, caster, distortion
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, colmap_model, image_io, llff, random_poses

RIGS = ('auto', 'inward', 'forward')
# (Config field, its allowed values) of this loader's own settings, checked before any work.
SETTING_CHOICES = (('capture_rig', RIGS),)
FORWARD_SPREAD = 0.9   # 'auto': forward when the mean of the unit viewing directions is at least this long.
CAMERA_DISTANCE = 1.   # Inward captures are scaled so that the median camera is this far from the centre.


@dataclasses.dataclass
class Capture:
  """A capture in the loader's world frame: per image (name order) its file name, COLMAP camera parameters
  (distortion.opencv_params [8], at full size), camera-to-world [3,4] (OpenCV axes) and depth bounds [2]; the
  sparse points in the same frame."""
  folder: str
  names: List[str]
  params: np.ndarray     # [N, 8]
  camtoworlds: np.ndarray  # [N, 3, 4]
  bounds: np.ndarray     # [N, 2]
  sizes: np.ndarray      # [N, 2] (height, width) at full size.
  forward: bool
  points: np.ndarray     # [P, 3] the model's 3D points.


def scene_path(config) -> str:
  """The capture folder: Config.data_dir, or its sub-folder Config.capture_scene (both checked)."""
  if not config.capture_scene:
    base.require_data_folder(config.data_dir, 'a capture: the images and the COLMAP model')
    return config.data_dir
  return base.scene_dir(config.data_dir, config.capture_scene, 'capture_scene')


def _camera_params(model: colmap_model.Model, image: colmap_model.Image, path: str) -> np.ndarray:
  """distortion.opencv_params of an image's camera; DatasetError naming the cameras file, the camera and the
  image for an unsupported model, a focal length that is not positive or a value that is not finite."""
  camera = model.cameras[image.camera_id]
  where = f'{path!r}: camera {camera.camera_id} of image {image.name!r}'
  try:
    params = distortion.opencv_params(camera.model, camera.params)
  except distortion.UnsupportedCameraError as err:
    raise base.DatasetError(f'{where}: {err}') from err
  if not np.isfinite(params).all() or not (params[:2] > 0).all() or min(camera.width, camera.height) < 1:
    raise base.DatasetError(f'{where}: {camera.model} {camera.width} x {camera.height} with parameters '
                            f'{[float(v) for v in camera.params]}; expected positive focal lengths, finite values '
                            'and a size of at least 1 x 1 pixel')
  return params


def _is_forward(camtoworlds: np.ndarray, rig: str) -> bool:
  """Whether the capture is forward-facing: Config.capture_rig, or 'auto' by the spread of viewing directions."""
  if rig != 'auto':
    return rig == 'forward'
  return bool(np.linalg.norm(algebra.normalize(camtoworlds[:, :, 2]).mean(0)) >= FORWARD_SPREAD)


def read_capture(config) -> Capture:
  """The capture's images, cameras and bounds, in the world frame of its rig (see the module docstring)."""
  folder = scene_path(config)
  model_dir = os.path.join(folder, config.capture_model)
  model = colmap_model.read_model(model_dir)
  images = sorted(model.images.values(), key=lambda i: i.name)
  if not images:
    raise base.DatasetError(f'the COLMAP model in {model_dir!r} has no registered images')
  model_file = lambda name: os.path.join(model_dir, name + colmap_model.model_format(model_dir))
  c2w = np.stack([colmap_model.camtoworld(i) for i in images])
  base.check_cameras(c2w, model_file('images'), [f'image {i.name!r}' for i in images], 'pose')
  params = [_camera_params(model, i, model_file('cameras')) for i in images]
  bounds = colmap_model.depth_bounds(model, model_file('points3D'))
  cams = [model.cameras[i.camera_id] for i in images]
  capture = Capture(folder, [i.name for i in images], np.stack(params),
                    c2w, np.stack([bounds[i.image_id] for i in images]),
                    np.array([(c.height, c.width) for c in cams]), _is_forward(c2w, config.capture_rig),
                    np.array([p.xyz for p in model.points.values()]).reshape(-1, 3))
  return _to_forward_frame(capture) if capture.forward else _to_object_frame(capture)


def _up_rotation(up: np.ndarray) -> np.ndarray:
  """[3,3] rotation taking the unit vector up [3] to +z (Rodrigues about up x z)."""
  axis, cos = np.cross(up, [0., 0., 1.]), up[2]
  if np.linalg.norm(axis) < 1e-12:
    return np.eye(3) if cos > 0 else np.diag([1., -1., -1.])
  k = np.array([[0., -axis[2], axis[1]], [axis[2], 0., -axis[0]], [-axis[1], axis[0], 0.]])
  return np.eye(3) + k + k @ k / (1. + cos)


def _to_object_frame(capture: Capture) -> Capture:
  """The inward capture centred on the focus point of its optical axes, scaled, its mean up along +z."""
  centre = algebra.focus_point(capture.camtoworlds)
  scale = CAMERA_DISTANCE / np.median(np.linalg.norm(capture.camtoworlds[:, :, 3] - centre, axis=-1))
  rotation = _up_rotation(algebra.normalize(-capture.camtoworlds[:, :, 1].mean(0)))
  c2w = np.concatenate([rotation @ capture.camtoworlds[:, :, :3],
                        (scale * (capture.camtoworlds[:, :, 3] - centre) @ rotation.T)[..., None]], -1)
  return dataclasses.replace(capture, camtoworlds=c2w, bounds=capture.bounds * scale,
                             points=scale * (capture.points - centre) @ rotation.T)


def _to_forward_frame(capture: Capture) -> Capture:
  """The forward capture in LLFF's frame: scaled so that the nearest bound is 1 / 0.75, recentred on the mean
  pose (computed in OpenGL axes, as LLFF's), the cameras looking down -z."""
  scale = 1. / (capture.bounds.min() * .75)
  c2w_gl = capture.camtoworlds @ np.diag([1., -1., -1., 1.])
  c2w_gl[:, :, 3] *= scale
  to_frame = np.linalg.inv(algebra.to_homogeneous(algebra.poses_avg(c2w_gl)))  # What recenter_poses applies.
  c2w = (to_frame @ algebra.to_homogeneous(c2w_gl))[:, :3, :4] @ np.diag([1., -1., -1., 1.])
  points = scale * capture.points @ to_frame[:3, :3].T + to_frame[:3, 3]
  return dataclasses.replace(capture, camtoworlds=c2w, bounds=capture.bounds * scale, points=points)


def arc_order(capture: Capture) -> List[int]:
  """Image indices along the capture: by azimuth about +z starting after the widest gap (inward), else names."""
  if capture.forward:
    return list(range(len(capture.names)))
  centres = capture.camtoworlds[:, :, 3]
  azimuth = np.arctan2(centres[:, 1], centres[:, 0])
  order = np.argsort(azimuth)
  gaps = np.diff(np.concatenate([azimuth[order], azimuth[order[:1]] + 2. * np.pi]))
  start = (int(np.argmax(gaps)) + 1) % len(order)
  return [int(i) for i in np.roll(order, -start)]


def default_views(capture: Capture, llffhold: int, n_views: int) -> Dict[str, List[int]]:
  """{'train', 'test'} ids by the documented rule: every llffhold-th along the arc for test, n_views spread
  evenly over the rest for training (all of them for n_views 0)."""
  if llffhold < 1:
    raise base.DatasetError(f'Config.llffhold = {llffhold}; expected a positive integer')
  order = arc_order(capture)
  test = [i for k, i in enumerate(order) if k % llffhold == 0]
  pool = [i for k, i in enumerate(order) if k % llffhold]
  if n_views > len(pool):
    raise base.DatasetError(f'Config.n_input_views = {n_views} exceeds the {len(pool)} training views of the '
                            f'capture {capture.folder!r} ({len(capture.names)} registered images, every '
                            f'{llffhold}-th held out for testing); ask for fewer views or lower Config.llffhold')
  train = pool if base.all_views(n_views, len(pool), 'the capture') else [
      pool[int(round(v))] for v in np.linspace(0, len(pool) - 1, n_views)]
  return {'train': train, 'test': test}


def _image_paths(capture: Capture, config, factor: int) -> tuple:
  """(paths of every image at factor or a finer copy, extra downsampling); a model naming an absent image is named."""
  folder, extra = llff.image_folder(capture.folder, factor, config.capture_images)
  paths = [os.path.join(folder, name) for name in capture.names]
  missing = [p for p in paths if not os.path.isfile(p)]
  if missing:
    raise base.DatasetNotFoundError(f'{len(missing)} of the {len(paths)} images the COLMAP model in '
                                    f'{os.path.join(capture.folder, config.capture_model)!r} registers are not in '
                                    f'{folder!r}: {missing[:5]}')
  return paths, extra


def cameras_of(capture: Capture, rows, width: int) -> Cameras:
  """The Cameras of images rows of capture at the loaded width: COLMAP's parameters (the rays invert their
  distortion per pixel) and the pixtocams of their undistorted pinholes."""
  factors = [capture.sizes[i, 1] / width for i in rows]
  return Cameras(capture.camtoworlds[rows],
                 np.stack([np.linalg.inv(_intrinsics(capture.params[i], f)) for i, f in zip(rows, factors)]),
                 np.stack([distortion.scaled(capture.params[i], f) for i, f in zip(rows, factors)]))


def ray_space(capture: Capture, height: int, width: int) -> RaySpace:
  """A capture's rays: OpenCV cameras; LLFF's NDC of the first image's focal length for forward captures, else
  world rays between near_far's bounds."""
  near, far = near_far(capture)
  return RaySpace(opengl=False, near=near, far=far, height=height, width=width,
                  ndc_focal=_ndc_focal(capture, width) if capture.forward else 0.)


def _ndc_focal(capture: Capture, width: int) -> float:
  """The focal length (pixels at the loaded width) that defines NDC space: the first image's, as LLFF's."""
  return capture.params[0, 0] * width / capture.sizes[0, 1]


def near_far(capture: Capture) -> tuple:
  """(near, far) of every ray: the caster's NDC range for forward captures, else the extremes of the image bounds."""
  if capture.forward:
    return caster.NDC_NEAR_FAR
  return float(capture.bounds[:, 0].min()), float(capture.bounds[:, 1].max())


def check_size(capture: Capture, index: int, image: np.ndarray, factor: int, path: str) -> None:
  """Raises DatasetError naming the file when an image's size is not its camera's divided by factor."""
  expected = tuple(int(s) // factor for s in capture.sizes[index])
  if image.shape[:2] != expected:
    raise base.DatasetError(f'{path!r} is {image.shape[1]} x {image.shape[0]} pixels; its COLMAP camera is '
                            f'{capture.sizes[index, 1]} x {capture.sizes[index, 0]}, so {expected[1]} x '
                            f'{expected[0]} at Config.factor {factor} (images are read as stored, as COLMAP read '
                            'them)')


def warn_cropped(paths: List[str], factor: int, mode: str) -> None:
  """One warning when 'area' downsampling by factor crops images (any size trains: their last rows and columns,
  which fill no block, are left out, as tools.capture's images_<k>/ leave them out; the cameras stay exact)."""
  sizes = sorted({image_io.image_size(p) for p in paths}) if mode == 'area' and factor > 1 else []
  cropped = [f'{w} x {h} to {w - w % factor} x {h - h % factor}' for h, w in sizes if h % factor or w % factor]
  if cropped:
    warnings.warn(f'{os.path.dirname(paths[0])!r}: images cropped from {", ".join(cropped)} pixels (the last rows '
                  f"and columns, which fill no {factor} x {factor} block) to average them down by {factor} "
                  "(Config.downsample_mode = 'area'); the cameras are unchanged", stacklevel=2)


def load_scene(split: str, config) -> base.Dataset:
  """One split of the capture (see the module docstring for its frame, rays and views)."""
  capture = read_capture(config)
  factor = base.load_factor(config, split)
  paths, extra = _image_paths(capture, config, factor)
  ids = base.choose_views(config, split, lambda s: default_views(capture, config.llffhold, config.n_input_views)[s],
                          len(paths), f'the capture {capture.folder!r}')
  index = {path: i for i, path in enumerate(paths)}

  def load(path):  # Each image against its own camera first (a rotated photo is named, not its neighbour).
    image = image_io.read_image(path, 'RGB')
    cropped = image_io.crop_to_blocks(image, extra) if config.downsample_mode == 'area' else image
    image = image_io.downsample(cropped, extra, config.downsample_mode)
    check_size(capture, index[path], image, factor, path)
    return image

  warn_cropped([paths[i] for i in ids], extra, config.downsample_mode)
  images = image_io.load_stack([paths[i] for i in ids], load)
  height, width = images.shape[1:3]
  source, rows = _camera_source(config, split, capture, ids)
  cameras, space = cameras_of(source, rows, width), ray_space(source, height, width)
  return base.Dataset(images=images, camtoworlds=cameras.camtoworlds.astype(np.float32),
                      pixtocams=cameras.pixtocams.astype(np.float32), ids=list(ids), height=height,
                      width=width, near=space.near, far=space.far, masks=None, rays=caster.image_rays(cameras, space),
                      split=split, name=f'capture/{scene_name(config)}', image_paths=[paths[i] for i in ids],
                      space=space, distortion=cameras.distortion.astype(np.float32))


def _camera_source(config, split: str, capture: Capture, ids) -> tuple:
  """(capture, indices into it) whose cameras the views ids of capture take: for the training split those of
  Config.capture_train_model (matched by image name, in that model's own frame and capture's rig), else capture's
  own."""
  if split != 'train' or not config.capture_train_model:
    return capture, list(ids)
  model = os.path.abspath(config.capture_train_model)
  own = read_capture(dataclasses.replace(config, capture_model=model,
                                         capture_rig='forward' if capture.forward else 'inward'))
  position = {name: i for i, name in enumerate(own.names)}
  missing = [capture.names[i] for i in ids if capture.names[i] not in position]
  if missing:
    raise base.DatasetError(f'Config.capture_train_model = {config.capture_train_model!r}: the training photos '
                            f'{missing} are not registered in {model!r} (it registers {own.names[:10]}); choose '
                            'training views among its photos (Config.train_view_ids)')
  return own, [position[capture.names[i]] for i in ids]


def _intrinsics(params: np.ndarray, factor: float) -> np.ndarray:
  """K [3,3] of the undistorted pinhole part of a camera for images downsampled by factor."""
  fx, fy, cx, cy = distortion.scaled(params, factor)[:4]
  return np.array([[fx, 0., cx], [0., fy, cy], [0., 0., 1.]])


def scene_name(config) -> str:
  """The capture's name in metrics.json and the tables: its folder's name."""
  return os.path.basename(os.path.normpath(scene_path(config)))


def is_ndc(config):
  """True for forward captures (NDC rays), False for inward ones; under capture_rig 'auto' the capture decides,
  None while it cannot be read (its loading then names what is missing)."""
  if config.capture_rig != 'auto':
    return config.capture_rig == 'forward'
  try:
    return read_capture(config).forward
  except (base.DatasetError, OSError):
    return None


def orbit_path(capture: Capture, n_frames: int) -> np.ndarray:
  """[F,3,4] OpenCV cameras on the cameras' mean distance and height about +z, looking at the centre, over the
  captured arc of azimuths and back."""
  centres = capture.camtoworlds[:, :, 3]
  order = arc_order(capture)
  azimuth = np.unwrap(np.arctan2(centres[order, 1], centres[order, 0]))
  radius, height = np.linalg.norm(centres[:, :2], axis=-1).mean(), centres[:, 2].mean()
  sweep = np.concatenate([np.linspace(azimuth[0], azimuth[-1], (n_frames + 1) // 2),
                          np.linspace(azimuth[-1], azimuth[0], n_frames // 2)])
  positions = np.stack([radius * np.cos(sweep), radius * np.sin(sweep), np.full_like(sweep, height)], -1)
  return np.stack([algebra.viewmatrix(-p, np.array([0., 0., -1.]), p) for p in positions])


def random_pose_cameras(dataset: base.Dataset, config, rng: np.random.Generator) -> Cameras:
  """RegNeRF's random poses of the capture (OpenCV cameras without distortion): DTU's rule for inward captures (in
  the box of the captured cameras, looking at the centre; the training images' mean intrinsics), LLFF's for
  forward ones (all n poses: no released code keeps only the last for captures; the NDC focal length's pinhole)."""
  capture = read_capture(config)
  if not capture.forward:
    poses = random_poses.dtu_random_poses(capture.camtoworlds, config.n_random_poses, rng,
                                          config.random_pose_radius, config.random_pose_focusptjitter)
    return Cameras(poses, np.broadcast_to(dataset.pixtocams.mean(0).astype(np.float64), (len(poses), 3, 3)))
  opengl = random_poses.llff_random_poses(capture.camtoworlds @ np.diag([1., -1., -1., 1.]), capture.bounds,
                                          config.n_random_poses, rng, keep_last_only=False)
  pixtocam = algebra.focal_pixtocam(_ndc_focal(capture, dataset.width), dataset.height, dataset.width)
  return Cameras(opengl @ np.diag([1., -1., -1., 1.]), np.broadcast_to(pixtocam, (len(opengl), 3, 3)))


def mesh_bounds(config):
  """[2, 3] the region to mesh of an inward capture: the box around its sparse points inside the sphere of the
  median camera distance about the centre, which the cameras orbit (None: forward captures, meshed in the NDC box,
  or no point inside)."""
  capture = read_capture(config)
  inside = capture.points[np.linalg.norm(capture.points, axis=-1) < CAMERA_DISTANCE]
  if capture.forward or not len(inside):
    return None
  return np.stack([inside.min(0), inside.max(0)])


def scene_render_path(config):
  """Rays [F,H,W,...] of the render path: the arc orbit (inward) or LLFF's spiral (forward), first camera's
  intrinsics without distortion, at Config.render_factor."""
  capture = read_capture(config)
  factor = base.render_factor(config)
  height, width = (int(s) // factor for s in capture.sizes[0])
  params = np.concatenate([capture.params[0, :4], np.zeros(4)])
  capture = dataclasses.replace(capture, params=params[None].repeat(len(capture.names), 0))
  if capture.forward:
    poses = algebra.spiral_path_llff(capture.camtoworlds @ np.diag([1., -1., -1., 1.]), capture.bounds,
                                     config.render_path_frames) @ np.diag([1., -1., -1., 1.])
  else:
    poses = orbit_path(capture, config.render_path_frames)
  path = dataclasses.replace(capture, camtoworlds=poses, sizes=capture.sizes[:1].repeat(len(poses), 0),
                             params=capture.params[:1].repeat(len(poses), 0))
  return caster.image_rays(cameras_of(path, range(len(poses)), width), ray_space(path, height, width))
