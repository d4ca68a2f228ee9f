"""The training cameras of a run that refines them, written after training into <run dir>/cameras/.

given/ and refined/ are COLMAP text models (cameras.txt: each view's pinhole intrinsics at the training size;
images.txt: its world-to-camera pose in COLMAP's axes; points3D.txt: empty), which COLMAP's tools, pycolmap and the
project's colmap_model read (tools.capture's camera picture draws them); cameras.json holds the view ids, the image
names and both sets of camera-to-world matrices [N, 3, 4] in the axes the loader keeps them in. All are in the
frame the run trained in: the loader's (for a capture, its normalized frame, not COLMAP's original one).
"""

import json
import os

import numpy as np

from internal import atomic
from internal.cameras import algebra
from internal.datasets import base, colmap_model
from internal.datasets import capture as capture_loader
from internal.training import camera_refinement

FOLDER = 'cameras'
OPENGL_TO_OPENCV = np.diag([1., -1., -1.])


def image_names(config, dataset: base.Dataset) -> list:
  """The views' image names: a capture's file names, else view_<id>.png."""
  if config.dataset_loader == 'capture':
    names = capture_loader.read_capture(config).names
    return [names[i] for i in dataset.ids]
  return [f'view_{i:03d}.png' for i in dataset.ids]


def colmap_cameras(camtoworlds: np.ndarray, dataset: base.Dataset, names: list, opengl: bool) -> colmap_model.Model:
  """A COLMAP model (no points) of cameras [N, 3, 4] with dataset's intrinsics and image size."""
  rotations = camtoworlds[:, :, :3] @ OPENGL_TO_OPENCV if opengl else camtoworlds[:, :, :3]
  cameras, images = {}, {}
  for k, (rotation, centre, pixtocam, name) in enumerate(zip(rotations, camtoworlds[:, :, 3], dataset.pixtocams,
                                                             names), start=1):
    intrinsics = np.linalg.inv(np.asarray(pixtocam, np.float64))
    params = np.array([intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]])
    cameras[k] = colmap_model.Camera(k, 'PINHOLE', dataset.width, dataset.height, params)
    images[k] = colmap_model.Image(k, algebra.rotation_to_quaternion(rotation.T), -rotation.T @ centre, k, name,
                                   np.zeros(0, colmap_model.POINT2D))
  return colmap_model.Model(cameras, images, {})


def write(run_dir: str, config, dataset: base.Dataset, camera_state) -> str:
  """Writes the given and refined training cameras of dataset (as trained on) into <run_dir>/cameras/; its path."""
  folder = os.path.join(run_dir, FOLDER)
  given = np.asarray(dataset.camtoworlds, np.float64)
  sets = {'given': given, 'refined': camera_refinement.refined_cameras(camera_state, given)}
  names, opengl = image_names(config, dataset), dataset.space.opengl
  for label, c2w in sets.items():
    colmap_model.write_text(colmap_cameras(c2w, dataset, names, opengl), os.path.join(folder, label))
  record = {'ids': [int(i) for i in dataset.ids], 'names': names, 'axes': 'OpenGL' if opengl else 'OpenCV',
            **{label: c2w.tolist() for label, c2w in sets.items()}}
  atomic.write_text(os.path.join(folder, 'cameras.json'), json.dumps(record, indent=1))
  return folder
