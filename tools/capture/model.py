"""The capture's COLMAP model: the largest model structure-from-motion found, its images named as in images/ and its
cameras scaled from the structure-from-motion copies back to the full images, written as sparse/0.

COLMAP's pixel coordinates span [0, width] x [0, height], so a camera seen at another size scales by the ratio of
the sizes: focal lengths and principal point, and every 2D point; distortion coefficients act on normalized
coordinates and stay.
"""

import dataclasses
from typing import Dict, List, Tuple

import numpy as np

from internal.datasets import colmap_model

# Per camera model the loader reads: which size ratio (x: width, y: height) scales each parameter; None keeps it.
SCALED_BY = {'SIMPLE_PINHOLE': ('x', 'x', 'y'), 'PINHOLE': ('x', 'y', 'x', 'y'),
             'SIMPLE_RADIAL': ('x', 'x', 'y', None), 'RADIAL': ('x', 'x', 'y', None, None),
             'OPENCV': ('x', 'y', 'x', 'y', None, None, None, None)}
CAMERA_MODELS = tuple(SCALED_BY)


def scaled_camera(camera: colmap_model.Camera, width: int, height: int) -> colmap_model.Camera:
  """The camera for images of width x height instead of its own size."""
  ratio = {'x': width / camera.width, 'y': height / camera.height, None: 1.}
  params = np.array([p * ratio[axis] for p, axis in zip(camera.params, SCALED_BY[camera.model])])
  return dataclasses.replace(camera, width=width, height=height, params=params)


def full_size_model(model: colmap_model.Model, names: Dict[str, str],
                    sizes: Dict[str, Tuple[int, int]]) -> colmap_model.Model:
  """The model with its images renamed by names ({name in the model: name in images/}) and its cameras and 2D
  points scaled to sizes ({name in images/: (width, height)})."""
  cameras, images = {}, {}
  for image in model.images.values():
    name = names[image.name]
    camera = model.cameras[image.camera_id]
    width, height = sizes[name]
    cameras[camera.camera_id] = scaled_camera(camera, width, height)
    points = image.points2d.copy()
    points['x'] *= width / camera.width
    points['y'] *= height / camera.height
    images[image.image_id] = dataclasses.replace(image, name=name, points2d=points)
  return colmap_model.Model(cameras, images, model.points)


def observations(model: colmap_model.Model) -> Dict[str, int]:
  """{image name: how many of its 2D points are 3D points of the model}: what its registration rests on."""
  return {i.name: int((i.points2d['point3d_id'] >= 0).sum()) for i in model.images.values()}


def reprojection_error(model: colmap_model.Model) -> float:
  """The mean reprojection error of the model's 3D points, in pixels of the images structure-from-motion saw."""
  return float(np.mean([p.error for p in model.points.values()])) if model.points else float('nan')


def names_in_order(model: colmap_model.Model) -> List[str]:
  """The registered images' names in the loader's order (file-name order): its view ids."""
  return sorted(i.name for i in model.images.values())
