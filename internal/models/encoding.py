"""Positional encodings: mip-NeRF's released order [identity | sin block | cos block] and NeRF's interleaved one."""

import jax
import numpy as np
import jax.numpy as jnp

from internal.models import trig


def safe_sin(x):
  """sin(x) [...] with x taken mod 100*pi when |x| >= 100*pi (float32 precision guard)."""
  period = 100. * jnp.pi
  return trig.sin(jnp.where(jnp.abs(x) < period, x, trig.remainder(x, period)))


def _lift(x, min_deg, max_deg, power, append_identity, interleaved=False):
  """x [..., C] -> [..., L] in feature_layout's order: x_c * (2^power)^deg, identity columns x_c (0 if power != 1).

  A matmul with one power of two per column, so exact; unlike broadcasting and concatenating, it leaves the
  encodings' transcendental functions one element-wise loop over contiguous columns, which XLA vectorizes.
  """
  kind, degree, coord = feature_layout(max_deg - min_deg, x.shape[-1], append_identity, interleaved)
  scale = np.where(kind == 0, float(power == 1), (2.**power)**(degree + min_deg))
  matrix = np.zeros((x.shape[-1], len(kind)), np.float32)
  matrix[coord, np.arange(len(kind))] = scale
  return jnp.matmul(x, matrix, precision=jax.lax.Precision.HIGHEST), kind


def _with_identity(x, kind, features):
  """features [..., L] of an encoding, its identity columns (kind 0 of kind [L]) taken from x [..., L] instead."""
  return jnp.where(kind == 0, x, features)


def _cos_shift(kind):
  """pi/2 for the cos columns of kind [L], else 0: the released encodings take cos(y) as sin(y + pi/2)."""
  return np.where(kind == 2, np.float32(0.5 * np.pi), np.float32(0.))


def pos_enc(x, min_deg, max_deg, append_identity=True):
  """x [...,C] -> [..., C*(append_identity + 2*(max_deg-min_deg))]: [x | sin | cos]."""
  y, kind = _lift(x, min_deg, max_deg, 1, append_identity)
  return _with_identity(y, kind, trig.sin(y + _cos_shift(kind)))


def integrated_pos_enc(mean, cov_diag, min_deg, max_deg, append_identity=True):
  """Expected pos_enc under N(mean [...,C], diag(cov_diag [...,C])); same length and order."""
  y, kind = _lift(mean, min_deg, max_deg, 1, append_identity)
  y_var, _ = _lift(cov_diag, min_deg, max_deg, 2, append_identity)
  return _with_identity(y, kind, jnp.exp(-0.5 * y_var) * safe_sin(y + _cos_shift(kind)))


def interleaved_pos_enc(x, num_degrees, append_identity=True):
  """NeRF's encoding of x [...,C] -> [..., C*(append_identity + 2D)]: [x, sin(2^0 x), cos(2^0 x), sin(2^1 x), ...]."""
  y, kind = _lift(x, 0, num_degrees, 1, append_identity, interleaved=True)
  sin, cos = trig.sin_cos(y)
  return _with_identity(y, kind, jnp.where(kind == 1, sin, cos))


def width(num_degrees, num_coords=3, append_identity=True):
  """Length of pos_enc / integrated_pos_enc over num_degrees degrees of num_coords coordinates."""
  return num_coords * (int(append_identity) + 2 * num_degrees)


def feature_layout(num_degrees, num_coords=3, append_identity=True, interleaved=False):
  """Index map of an encoding: (kind [L], degree [L], coord [L]) int; kind 0 id (deg -1), 1 sin, 2 cos.

  interleaved: NeRF's order (interleaved_pos_enc), else the released block order (pos_enc).
  """
  if interleaved:
    layout = _interleaved_layout(num_degrees, num_coords)
    return layout if append_identity else tuple(a[num_coords:] for a in layout)
  band_degree = np.repeat(np.arange(num_degrees), num_coords)
  band_coord = np.tile(np.arange(num_coords), num_degrees)
  kinds = [np.full(band_degree.shape, 1), np.full(band_degree.shape, 2)]
  degrees = [band_degree, band_degree]
  coords = [band_coord, band_coord]
  if append_identity:
    kinds.insert(0, np.zeros(num_coords, int))
    degrees.insert(0, np.full(num_coords, -1))
    coords.insert(0, np.arange(num_coords))
  return tuple(np.concatenate(a).astype(np.int64) for a in (kinds, degrees, coords))


def _interleaved_layout(num_degrees, num_coords):
  """feature_layout of interleaved_pos_enc: identity, then per degree sin of every coord, cos of every coord."""
  kind = np.concatenate([np.zeros(num_coords, int), np.tile(np.repeat([1, 2], num_coords), num_degrees)])
  degree = np.concatenate([np.full(num_coords, -1), np.repeat(np.arange(num_degrees), 2 * num_coords)])
  coord = np.tile(np.arange(num_coords), 1 + 2 * num_degrees)
  return kind.astype(np.int64), degree.astype(np.int64), coord.astype(np.int64)
