"""BARF's coarse-to-fine weighting of the positional encoding (Lin et al., BARF, ICCV 2021, eq. 14-15).

Frequency band k of an encoding of L bands (sin and cos of degree k, every coordinate) is weighted by
(1 - cos(pi * clip(alpha - k, 0, 1))) / 2, where alpha rises linearly from 0 to L while the training progress
(step / Config.max_steps) goes from Config.coarse_to_fine_start to Config.coarse_to_fine_end (BARF: 0.1 and 0.5);
the raw coordinates always have weight 1. A band's weight scales its features and so the gradient that reaches the
cameras through them (camera refinement): early on the cameras see only a smooth, low-frequency scene. Unlike
FreeNeRF's frequency mask (freq_schedule.py: 1e-8 for closed features, bands opened 3 features at a time) every
band opens smoothly and the schedule is set in fractions of the run. Off by default (Config.coarse_to_fine); where
both are on, the model's encodings take the product of the two (freq_schedule.model_masks), at the point and the
view-direction encodings alike, as BARF weights both.
"""

import warnings

import jax.numpy as jnp
import numpy as np

from internal.configs import Config
from internal.models import encoding


def band_weights(num_bands: int, step, max_steps: int, start: float, end: float):
  """f32 [num_bands]: the weights of bands 0..L-1 at a (possibly traced) step; start < end fractions of max_steps."""
  progress = jnp.asarray(step, jnp.float32) / jnp.float32(max_steps)
  alpha = num_bands * (progress - jnp.float32(start)) / jnp.float32(end - start)
  opened = jnp.clip(alpha - jnp.arange(num_bands, dtype=jnp.float32), 0., 1.)
  return (1. - jnp.cos(jnp.float32(np.pi) * opened)) / 2.


def feature_weights(num_degrees: int, step, max_steps: int, start: float, end: float, interleaved=False):
  """f32 [encoding.width(num_degrees)]: band_weights spread over an encoding's features in its order (the
  identity columns first, weight 1); interleaved: NeRF's feature order, else mip-NeRF's block order."""
  _, degree, _ = encoding.feature_layout(num_degrees, append_identity=True, interleaved=interleaved)
  bands = band_weights(num_degrees, step, max_steps, start, end)
  return jnp.where(degree < 0, 1., bands[np.maximum(degree, 0)])


def weights_at(config: Config, degrees, step, interleaved=False):
  """Weights (point, view) of Config for the encoding degrees (point, view) at a (possibly traced) step; (None,
  None) when Config.coarse_to_fine is off."""
  if not config.coarse_to_fine:
    return None, None
  return tuple(feature_weights(d, step, config.max_steps, config.coarse_to_fine_start, config.coarse_to_fine_end,
                               interleaved) for d in degrees)


def check_settings(config: Config) -> None:
  """With Config.coarse_to_fine on: raises a ValueError naming the settings when the schedule is not
  0 <= start < end (warns when end > 1). Off, its settings are read by nothing."""
  start, end = config.coarse_to_fine_start, config.coarse_to_fine_end
  if not config.coarse_to_fine:
    return
  if not 0. <= start < end:
    raise ValueError(f'Config.coarse_to_fine_start = {start} and Config.coarse_to_fine_end = {end}; expected '
                     '0 <= start < end (fractions of Config.max_steps; BARF: 0.1 and 0.5)')
  if end > 1.:
    warnings.warn(f'Config.coarse_to_fine_end = {end} exceeds 1: the encoding never fully opens during training',
                  stacklevel=4)
