"""Seeded noise on the training cameras, for studies of camera refinement (Config.camera_noise_*).

Each training camera turns by exactly Config.camera_noise_rotation_deg about a random axis through its centre and
moves by exactly Config.camera_noise_translation times the camera distance (cameras/alignment.camera_distance) in
a random direction; the directions of view id v come from np.random.default_rng([Config.camera_noise_seed, v]), so a
view's noise does not depend on which other views train. Test cameras are never perturbed. Noise that moves a camera
or its rays beyond float32's range, the precision they train in, is one error naming
Config.camera_noise_translation.
"""

import dataclasses

import numpy as np

from internal.cameras import alignment, corrections
from internal.datasets import base


def is_on(config) -> bool:
  """Whether Config asks for noise on the training cameras."""
  return config.camera_noise_rotation_deg > 0 or config.camera_noise_translation > 0


def _unit(rng: np.random.Generator) -> np.ndarray:
  """A direction [3] uniform on the sphere."""
  v = rng.normal(size=3)
  return v / np.linalg.norm(v)


def draw(ids, config, distance: float) -> tuple:
  """(rotations [N,3,3], shifts [N,3]) of the noise of view ids [N] (float64)."""
  angle = np.deg2rad(config.camera_noise_rotation_deg)
  rotations, shifts = [], []
  for view in ids:
    rng = np.random.default_rng([config.camera_noise_seed, int(view)])
    axis, direction = _unit(rng), _unit(rng)
    rotations.append(corrections.so3_exp(angle * axis))
    shifts.append(config.camera_noise_translation * distance * direction)
  return np.stack(rotations), np.stack(shifts)


def _check_float32(config, distance: float, arrays) -> None:
  """ValueError naming Config.camera_noise_translation when moved cameras (float64) or rays (float32: inf beyond
  its range) leave float32's range: they would train as inf."""
  if not all(np.all(np.abs(x) <= np.finfo(np.float32).max) for x in arrays):  # NaN fails the comparison too.
    shift = config.camera_noise_translation * distance
    raise ValueError(f'Config.camera_noise_translation = {config.camera_noise_translation} moves the training '
                     f'cameras by {shift:.4g} (x the camera distance {distance:g}), beyond float32\'s range '
                     f'({np.finfo(np.float32).max:.4g}) in which they train; expected a fraction of the camera '
                     'distance that keeps them there')


def perturbed(dataset: base.Dataset, config) -> base.Dataset:
  """The training dataset with its cameras and rays turned and moved by the noise (unchanged when off)."""
  if not is_on(config) or dataset.split != 'train':
    return dataset
  distance = alignment.camera_distance(dataset.camtoworlds, dataset.space)
  rotations, shifts = draw(dataset.ids, config, distance)
  c2w = corrections.corrected_cameras(dataset.camtoworlds, rotations, shifts)
  _check_float32(config, distance, [c2w])  # Before their rays, which would overflow casting to float32.
  rays = corrections.corrected_image_rays(dataset.rays, dataset.cameras, rotations, shifts, dataset.space)
  _check_float32(config, distance, rays)
  return dataclasses.replace(dataset, camtoworlds=c2w.astype(np.float32), rays=rays)
