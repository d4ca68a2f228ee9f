"""Sparse depth of a capture's views from its structure-from-motion points (DS-NeRF's depth supervision).

A training view's prior: the 3D points whose tracks hold at least MIN_TRAINING_VIEWS training views, at the
pixels where that view observed them, each weighted by how well the point reprojects: exp(-(e / mean e)^2) of its
reprojection error e. What this leaks: the capture's own model was triangulated from every photo, test views
included, so its points (and the cameras the loader reads) carry information the training views alone do not
have. The strict form reads a model made from the training photos alone (Config.sfm_depth_model), aligned to the
capture by the similarity between its cameras and the capture's (matched by image name; cameras/alignment.fit).

Depths are the rays' parameter t: camera z-depth for world rays, NDC t for forward captures; for evaluation
(test views) always the camera z-depth, the unit of internal/evaluation/depth_metrics.py.
"""

import dataclasses
import os
import warnings
from typing import Callable, List

import numpy as np

from internal.cameras import algebra, alignment
from internal.datasets import base, colmap_model
from internal.datasets import capture as capture_loader

MIN_TRAINING_VIEWS = 2  # A point triangulated from the training views alone needs two of them.
MAX_ALIGNMENT_ERROR = .05  # Of the cameras' spread: a model whose cameras fit the capture's worse is refused.


def align(model: colmap_model.Model, capture: capture_loader.Capture, where: str) -> alignment.Similarity:
  """The similarity from model's frame to the capture's loader frame (x -> scale rotation x + shift), fitted on the
  cameras both hold (by image name); DatasetError naming where for fewer than 3 shared images or cameras that do
  not fit."""
  index = {name: i for i, name in enumerate(capture.names)}
  shared = [image for image in model.images.values() if image.name in index]
  if len(shared) < 3:
    raise base.DatasetError(f'{where}: {len(shared)} of its images are images of the capture; aligning it to the '
                            'capture needs the cameras of 3 or more')
  source = np.stack([colmap_model.camtoworld(image) for image in shared])
  target = capture.camtoworlds[[index[image.name] for image in shared], :, 3]
  found = alignment.fit(source, capture.camtoworlds[[index[image.name] for image in shared]])
  error = np.linalg.norm(found.cameras(source)[:, :, 3] - target, axis=-1).max()
  spread = np.linalg.norm(target - target.mean(0), axis=-1).max()
  if error > MAX_ALIGNMENT_ERROR * spread:
    raise base.DatasetError(f'{where}: its cameras fit the capture\'s only to {error / spread:.1%} of their spread '
                            f'after a similarity (at most {MAX_ALIGNMENT_ERROR:.0%}); expected a model of the same '
                            'photos')
  return found


def view_depths(model: colmap_model.Model, similarity: alignment.Similarity, names: List[str], height: int,
                width: int, keep: Callable, ndc: bool) -> tuple:
  """(depth [N, H, W], weight [N, H, W]) f32 of the views names at height x width; 0 = no point.

  keep(set of the image names of a track) -> whether its point serves; a pixel observing several keeps the
  best-weighted one. ndc: depths as NDC t of a forward capture (1 + 1 / world z), else the camera z-depth in
  loader units.
  """
  names_of = {image.image_id: image.name for image in model.images.values()}
  by_name = {image.name: image for image in model.images.values()}
  ids = list(model.points)
  row_of = {point_id: k for k, point_id in enumerate(ids)}
  xyz = np.array([model.points[i].xyz for i in ids]).reshape(-1, 3)
  error = np.array([model.points[i].error for i in ids])
  serves = np.array([keep({names_of[j] for j in model.points[i].track['image_id'].tolist() if j in names_of})
                     for i in ids], bool)
  world_z = (similarity.scale * xyz @ similarity.rotation.T + similarity.shift)[:, 2]
  found = []  # Per view: (flat pixels, depths, point rows) of its observations that serve.
  for name in names:
    image = by_name.get(name)
    if image is None:
      found.append((np.zeros(0, int), np.zeros(0), np.zeros(0, int)))
      continue
    rows = np.array([row_of.get(int(i), -1) for i in image.points2d['point3d_id']], int)
    chosen = rows >= 0
    chosen[chosen] = serves[rows[chosen]]
    observed, rows = image.points2d[chosen], rows[chosen]
    camera = model.cameras[image.camera_id]
    z = (xyz[rows] @ algebra.quaternion_to_rotation(image.qvec).T + image.tvec)[:, 2]
    r = np.floor(observed['y'] * height / camera.height).astype(int)
    c = np.floor(observed['x'] * width / camera.width).astype(int)
    inside = (z > 0) & (r >= 0) & (r < height) & (c >= 0) & (c < width)
    value = 1. + 1. / world_z[rows] if ndc else similarity.scale * z
    found.append((r[inside] * width + c[inside], value[inside], rows[inside]))
  used = np.concatenate([rows for _, _, rows in found])
  mean_error = max(float(error[used].mean()), 1e-12) if used.size else 1.
  depth, weight = np.zeros((2, len(names), height * width), np.float32)
  for view, (pixel, value, rows) in enumerate(found):
    w = np.exp(-(error[rows] / mean_error)**2)
    order = np.lexsort((-w, pixel))  # By pixel, the best weight first.
    first = order[np.unique(pixel[order], return_index=True)[1]]
    depth[view, pixel[first]], weight[view, pixel[first]] = value[first], w[first]
  return depth.reshape(-1, height, width), weight.reshape(-1, height, width)


def _model(config, capture: capture_loader.Capture) -> tuple:
  """(model, where) of the points: Config.sfm_depth_model, else the capture's own."""
  folder = config.sfm_depth_model or os.path.join(capture.folder, config.capture_model)
  where = f'Config.sfm_depth_model = {folder!r}' if config.sfm_depth_model else f'the COLMAP model {folder!r}'
  if config.sfm_depth_model and not os.path.isdir(folder):
    raise base.DatasetNotFoundError(f'{where} is not a folder; expected a COLMAP model (cameras, images, points3D) '
                                    'made from the training photos')
  return colmap_model.read_model(folder), where


def training_prior(dataset: base.Dataset, config) -> tuple:
  """(depth [N, H, W], weight [N, H, W]) of the training views: the points of >= MIN_TRAINING_VIEWS of them."""
  capture = capture_loader.read_capture(config)
  model, where = _model(config, capture)
  names = [capture.names[i] for i in dataset.ids]
  missing = [name for name in names if name not in {image.name for image in model.images.values()}]
  if missing:  # Structure-from-motion on few photos often leaves some out: they get no sparse depth.
    warnings.warn(f'{where} did not register training images {missing}: they get no sparse depth', stacklevel=2)
  chosen = set(names)
  depth, weight = view_depths(model, align(model, capture, where), names, dataset.height, dataset.width,
                              lambda track: len(track & chosen) >= MIN_TRAINING_VIEWS, capture.forward)
  if not weight.any():
    raise base.DatasetError(f'{where}: none of its points is seen by {MIN_TRAINING_VIEWS} or more of the training '
                            f'images {names}; Config.sfm_depth_loss_mult has nothing to supervise')
  return depth, weight


def evaluation_depths(test_set: base.Dataset, config) -> np.ndarray:
  """Camera z-depths [N, H, W] (0 = none) of the capture's own points at the test views' observations."""
  capture = capture_loader.read_capture(config)
  model, where = _model(dataclasses.replace(config, sfm_depth_model=''), capture)
  return view_depths(model, align(model, capture, where), [capture.names[i] for i in test_set.ids],
                     test_set.height, test_set.width, lambda track: True, False)[0]
