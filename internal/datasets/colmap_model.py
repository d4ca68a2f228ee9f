"""COLMAP sparse models (cameras, images, 3D points) in COLMAP's binary and text formats: read and write.

COLMAP's conventions, kept as they are: an image's pose maps world to camera, x_cam = R(q) x_world + t, with the
unit quaternion q = (w, x, y, z); the camera looks down +z with x right and y down; pixel coordinates put the
centre of the top-left pixel at (0.5, 0.5).
"""

import dataclasses
import os
import struct
from typing import Dict, List

import numpy as np
from internal.cameras import algebra
from internal.datasets import base

# COLMAP's camera models: id -> (name, number of parameters). The readers know them all (so that an unsupported
# one is named); SUPPORTED are those whose projection internal/cameras/distortion.py inverts.
CAMERA_MODELS = {0: ('SIMPLE_PINHOLE', 3), 1: ('PINHOLE', 4), 2: ('SIMPLE_RADIAL', 4), 3: ('RADIAL', 5),
                 4: ('OPENCV', 8), 5: ('OPENCV_FISHEYE', 8), 6: ('FULL_OPENCV', 12), 7: ('FOV', 5),
                 8: ('SIMPLE_RADIAL_FISHEYE', 4), 9: ('RADIAL_FISHEYE', 5), 10: ('THIN_PRISM_FISHEYE', 12)}
MODEL_IDS = {name: model_id for model_id, (name, _) in CAMERA_MODELS.items()}
FILES = ('cameras', 'images', 'points3D')
POINT2D = np.dtype([('x', '<f8'), ('y', '<f8'), ('point3d_id', '<i8')])
TRACK = np.dtype([('image_id', '<i4'), ('point2d_idx', '<i4')])


class ColmapError(base.DatasetError):
  """A COLMAP model file is missing, truncated or not in COLMAP's format; the message names the file."""


@dataclasses.dataclass
class Camera:
  """One camera: its model name (CAMERA_MODELS), image size in pixels and parameters [P] as COLMAP orders them."""
  camera_id: int
  model: str
  width: int
  height: int
  params: np.ndarray


@dataclasses.dataclass
class Image:
  """One registered image: world-to-camera pose (qvec [4] w,x,y,z; tvec [3]), its camera, file name and its 2D
  points [K] (x, y, point3d_id; -1 where a point has no 3D point)."""
  image_id: int
  qvec: np.ndarray
  tvec: np.ndarray
  camera_id: int
  name: str
  points2d: np.ndarray


@dataclasses.dataclass
class Point3D:
  """One 3D point: position [3], colour [3] (uint8), reprojection error and track [T] (image_id, point2d_idx)."""
  point_id: int
  xyz: np.ndarray
  rgb: np.ndarray
  error: float
  track: np.ndarray


@dataclasses.dataclass
class Model:
  """A sparse model: cameras, images and points by id."""
  cameras: Dict[int, Camera]
  images: Dict[int, Image]
  points: Dict[int, Point3D]


def camera_center(image: Image) -> np.ndarray:
  """The camera centre [3] in world coordinates, -R^T t."""
  return -algebra.quaternion_to_rotation(image.qvec).T @ image.tvec


def camtoworld(image: Image) -> np.ndarray:
  """The camera-to-world [3, 4] of an image in COLMAP's (OpenCV) axes: [R^T | centre]."""
  return np.concatenate([algebra.quaternion_to_rotation(image.qvec).T, camera_center(image)[:, None]], -1)


def depth_bounds(model: Model, points_file: str = 'points3D', percentiles=(0.1, 99.9)) -> Dict[int, np.ndarray]:
  """{image_id: [near, far]}: percentiles of the camera-space depths of the 3D points whose track holds the
  image (LLFF's rule for poses_bounds.npy); ColmapError naming points_file for a point or a range that no ray
  could use (not finite, or not in front of the camera)."""
  seen: Dict[int, list] = {image_id: [] for image_id in model.images}
  for point in model.points.values():
    if not np.isfinite(point.xyz).all():
      raise ColmapError(f'{points_file!r}: 3D point {point.point_id} is at {point.xyz.tolist()}; expected finite '
                        'coordinates (the depth range of every image is computed from them)')
    for image_id in set(point.track['image_id'].tolist()):
      seen.setdefault(image_id, []).append(point.xyz)
  bounds = {}
  for image_id, image in model.images.items():
    if not seen[image_id]:
      raise ColmapError(f'image {image.name!r} sees none of the 3D points of {points_file!r}; its depth range is '
                        'unknown')
    depths = (np.array(seen[image_id]) @ algebra.quaternion_to_rotation(image.qvec).T + image.tvec)[:, 2]
    bounds[image_id] = np.percentile(depths, percentiles)
    if not (np.isfinite(bounds[image_id]).all() and 0 < bounds[image_id][0] <= bounds[image_id][1]):
      raise ColmapError(f'{points_file!r}: the 3D points image {image.name!r} sees give it the depth range '
                        f'{bounds[image_id].tolist()}; expected 0 < near <= far (points in front of the camera)')
  return bounds


class _Reader:
  """Little-endian reads from a binary file's bytes, with errors naming the file."""

  def __init__(self, path: str):
    self.path = path
    with open(path, 'rb') as f:
      self.data = f.read()
    self.offset = 0

  def read(self, fmt: str):
    size = struct.calcsize('<' + fmt)
    if self.offset + size > len(self.data):
      raise ColmapError(f'COLMAP model file {self.path!r} ends early (at byte {self.offset} of {len(self.data)}); '
                        'expected a complete model written by COLMAP')
    values = struct.unpack_from('<' + fmt, self.data, self.offset)
    self.offset += size
    return values

  def array(self, dtype: np.dtype, count: int) -> np.ndarray:
    self.read(f'{dtype.itemsize * count}x')
    return np.frombuffer(self.data, dtype, count, self.offset - dtype.itemsize * count).copy()

  def name(self) -> str:
    end = self.data.find(b'\0', self.offset)
    if end < 0:
      raise ColmapError(f'COLMAP model file {self.path!r}: an image name is not terminated')
    name, self.offset = self.data[self.offset:end].decode('utf-8'), end + 1
    return name

  def done(self) -> None:
    if self.offset != len(self.data):
      raise ColmapError(f'COLMAP model file {self.path!r} has {len(self.data) - self.offset} bytes after its last '
                        'entry; expected a model written by COLMAP')


def _model_name(model_id: int, camera_id: int, path: str) -> str:
  if model_id not in CAMERA_MODELS:
    raise ColmapError(f'{path!r}: camera {camera_id} has model id {model_id}, which COLMAP does not define '
                      f'(expected 0-{max(CAMERA_MODELS)})')
  return CAMERA_MODELS[model_id][0]


def read_cameras_binary(path: str) -> Dict[int, Camera]:
  """cameras.bin -> {camera_id: Camera}."""
  reader, cameras = _Reader(path), {}
  for _ in range(reader.read('Q')[0]):
    camera_id, model_id, width, height = reader.read('iiQQ')
    model = _model_name(model_id, camera_id, path)
    params = np.array(reader.read(f'{CAMERA_MODELS[model_id][1]}d'))
    cameras[camera_id] = Camera(camera_id, model, width, height, params)
  reader.done()
  return cameras


def read_images_binary(path: str) -> Dict[int, Image]:
  """images.bin -> {image_id: Image}."""
  reader, images = _Reader(path), {}
  for _ in range(reader.read('Q')[0]):
    image_id, *pose, camera_id = reader.read('i7di')
    name = reader.name()
    points2d = reader.array(POINT2D, reader.read('Q')[0])
    images[image_id] = Image(image_id, np.array(pose[:4]), np.array(pose[4:]), camera_id, name, points2d)
  reader.done()
  return images


def read_points_binary(path: str) -> Dict[int, Point3D]:
  """points3D.bin -> {point_id: Point3D}."""
  reader, points = _Reader(path), {}
  for _ in range(reader.read('Q')[0]):
    point_id, x, y, z, r, g, b, error = reader.read('Q3d3Bd')
    track = reader.array(TRACK, reader.read('Q')[0])
    points[point_id] = Point3D(point_id, np.array([x, y, z]), np.array([r, g, b], np.uint8), error, track)
  reader.done()
  return points


def _text_rows(path: str) -> List[List[str]]:
  """The lines of a COLMAP text file without comments, split on whitespace (empty lines kept: an image without
  2D points has an empty second line)."""
  with open(path, encoding='utf-8') as f:
    return [line.split() for line in f.read().splitlines() if not line.startswith('#')]


def _parse(path: str, row: List[str], what: str, convert):
  try:
    return convert(row)
  except (ValueError, IndexError, KeyError) as err:
    raise ColmapError(f'{path!r}: cannot read {what} from {" ".join(row)!r}: {err}') from err


def read_cameras_text(path: str) -> Dict[int, Camera]:
  """cameras.txt (CAMERA_ID MODEL WIDTH HEIGHT PARAMS...) -> {camera_id: Camera}."""
  cameras = {}
  for row in filter(None, _text_rows(path)):
    camera = _parse(path, row, 'a camera', lambda r: Camera(
        int(r[0]), r[1], int(r[2]), int(r[3]), np.array([float(v) for v in r[4:]])))
    if camera.model not in MODEL_IDS:
      raise ColmapError(f'{path!r}: camera {camera.camera_id} has model {camera.model!r}, which COLMAP does not '
                        f'define (expected one of {sorted(MODEL_IDS)})')
    cameras[camera.camera_id] = camera
  return cameras


def read_images_text(path: str) -> Dict[int, Image]:
  """images.txt (two lines an image: pose, camera and name; then its 2D points x y point3d_id ...)."""
  rows, images = _text_rows(path), {}
  while rows and not rows[-1]:
    rows.pop()
  for head, points in zip(rows[::2], rows[1::2] + [[]] * (len(rows) % 2)):
    image = _parse(path, head, 'an image', lambda r: Image(
        int(r[0]), np.array([float(v) for v in r[1:5]]), np.array([float(v) for v in r[5:8]]), int(r[8]),
        ' '.join(r[9:]), np.zeros(0, POINT2D)))
    triples = _parse(path, points, f'the 2D points of image {image.image_id}', lambda r: np.array(
        [(float(r[i]), float(r[i + 1]), int(r[i + 2])) for i in range(0, len(r) - len(r) % 3, 3)], POINT2D))
    image.points2d = triples
    images[image.image_id] = image
  return images


def read_points_text(path: str) -> Dict[int, Point3D]:
  """points3D.txt (POINT3D_ID X Y Z R G B ERROR then the track: IMAGE_ID POINT2D_IDX ...)."""
  points = {}
  for row in filter(None, _text_rows(path)):
    point = _parse(path, row, 'a 3D point', lambda r: Point3D(
        int(r[0]), np.array([float(v) for v in r[1:4]]), np.array([int(v) for v in r[4:7]], np.uint8),
        float(r[7]), np.array([(int(r[i]), int(r[i + 1])) for i in range(8, len(r) - 1, 2)], TRACK)))
    points[point.point_id] = point
  return points


READERS = {'.bin': (read_cameras_binary, read_images_binary, read_points_binary),
           '.txt': (read_cameras_text, read_images_text, read_points_text)}


def model_format(folder: str) -> str:
  """'.bin' or '.txt': the format of the complete model in folder (binary first, as COLMAP writes it)."""
  for ext in READERS:
    if all(os.path.isfile(os.path.join(folder, name + ext)) for name in FILES):
      return ext
  present = sorted(os.listdir(folder)) if os.path.isdir(folder) else None
  raise ColmapError(f'no COLMAP sparse model in {folder!r}: expected cameras, images and points3D as .bin or .txt'
                    + (f'; found {present}' if present is not None else ' (the folder does not exist)'))


def read_model(folder: str) -> Model:
  """The sparse model in folder (binary or text), its images checked against its cameras."""
  ext = model_format(folder)
  cameras, images, points = (read(os.path.join(folder, name + ext)) for read, name in zip(READERS[ext], FILES))
  for image in images.values():
    if image.camera_id not in cameras:
      raise ColmapError(f'{os.path.join(folder, "images" + ext)!r}: image {image.name!r} uses camera '
                        f'{image.camera_id}, which {os.path.join(folder, "cameras" + ext)!r} does not hold')
  return Model(cameras, images, points)


def write_binary(model: Model, folder: str) -> None:
  """Writes cameras.bin, images.bin and points3D.bin of model into folder."""
  os.makedirs(folder, exist_ok=True)
  with open(os.path.join(folder, 'cameras.bin'), 'wb') as f:
    f.write(struct.pack('<Q', len(model.cameras)))
    for c in model.cameras.values():
      f.write(struct.pack(f'<iiQQ{len(c.params)}d', c.camera_id, MODEL_IDS[c.model], c.width, c.height, *c.params))
  with open(os.path.join(folder, 'images.bin'), 'wb') as f:
    f.write(struct.pack('<Q', len(model.images)))
    for i in model.images.values():
      f.write(struct.pack('<i7di', i.image_id, *i.qvec, *i.tvec, i.camera_id) + i.name.encode('utf-8') + b'\0')
      f.write(struct.pack('<Q', len(i.points2d)) + np.asarray(i.points2d, POINT2D).tobytes())
  with open(os.path.join(folder, 'points3D.bin'), 'wb') as f:
    f.write(struct.pack('<Q', len(model.points)))
    for p in model.points.values():
      f.write(struct.pack('<Q3d3Bd', p.point_id, *p.xyz, *p.rgb, p.error))
      f.write(struct.pack('<Q', len(p.track)) + np.asarray(p.track, TRACK).tobytes())


def write_text(model: Model, folder: str) -> None:
  """Writes cameras.txt, images.txt and points3D.txt of model into folder (numbers in full precision)."""
  os.makedirs(folder, exist_ok=True)
  number = repr
  with open(os.path.join(folder, 'cameras.txt'), 'w', encoding='utf-8') as f:
    f.write('# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n')
    for c in model.cameras.values():
      f.write(' '.join([str(c.camera_id), c.model, str(c.width), str(c.height)]
                       + [number(float(v)) for v in c.params]) + '\n')
  with open(os.path.join(folder, 'images.txt'), 'w', encoding='utf-8') as f:
    f.write('# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n# POINTS2D[] as (X, Y, POINT3D_ID)\n')
    for i in model.images.values():
      pose = [number(float(v)) for v in (*i.qvec, *i.tvec)]
      f.write(' '.join([str(i.image_id)] + pose + [str(i.camera_id), i.name]) + '\n')
      f.write(' '.join(f'{number(float(x))} {number(float(y))} {int(p)}' for x, y, p in i.points2d) + '\n')
  with open(os.path.join(folder, 'points3D.txt'), 'w', encoding='utf-8') as f:
    f.write('# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n')
    for p in model.points.values():
      values = [str(p.point_id)] + [number(float(v)) for v in p.xyz] + [str(int(v)) for v in p.rgb]
      values += [number(float(p.error))] + [f'{int(a)} {int(b)}' for a, b in p.track]
      f.write(' '.join(values) + '\n')
