"""Positional encodings: mip-NeRF's released order [identity | sin block | cos block] and NeRF's interleaved one."""

import numpy as np
import jax.numpy as jnp


def safe_sin(x):
  """sin(x) [...] with x taken mod 100*pi when |x| >= 100*pi (float32 precision guard)."""
  period = 100. * jnp.pi
  return jnp.sin(jnp.where(jnp.abs(x) < period, x, jnp.remainder(x, period)))


def _scale(x, min_deg, max_deg, power):
  """x [...,C] -> [..., (max_deg-min_deg)*C] scaled by (2^power)^deg, degree-major, coord-minor."""
  scales = (2.**power)**jnp.arange(min_deg, max_deg, dtype=jnp.float32)
  xb = x[..., None, :] * scales[:, None]
  return xb.reshape(x.shape[:-1] + (-1,))


def pos_enc(x, min_deg, max_deg, append_identity=True):
  """x [...,C] -> [..., C*(append_identity + 2*(max_deg-min_deg))]: [x | sin | cos]."""
  xb = _scale(x, min_deg, max_deg, 1)
  four_feat = jnp.sin(jnp.concatenate([xb, xb + 0.5 * jnp.pi], axis=-1))
  return jnp.concatenate([x, four_feat], axis=-1) if append_identity else four_feat


def integrated_pos_enc(mean, cov_diag, min_deg, max_deg, append_identity=True):
  """Expected pos_enc under N(mean [...,C], diag(cov_diag [...,C])); same length and order."""
  y = _scale(mean, min_deg, max_deg, 1)
  y_var = _scale(cov_diag, min_deg, max_deg, 2)
  damp = jnp.exp(-0.5 * jnp.concatenate([y_var, y_var], axis=-1))
  enc = damp * safe_sin(jnp.concatenate([y, y + 0.5 * jnp.pi], axis=-1))
  return jnp.concatenate([mean, enc], axis=-1) if append_identity else enc


def interleaved_pos_enc(x, num_degrees, append_identity=True):
  """NeRF's encoding of x [...,C] -> [..., C*(append_identity + 2D)]: [x, sin(2^0 x), cos(2^0 x), sin(2^1 x), ...]."""
  xb = x[..., None, :] * (2.**jnp.arange(num_degrees, dtype=jnp.float32))[:, None]  # [..., D, C]
  bands = jnp.stack([jnp.sin(xb), jnp.cos(xb)], axis=-2).reshape(x.shape[:-1] + (-1,))  # [..., D, 2, C] flat
  return jnp.concatenate([x, bands], axis=-1) if append_identity else bands


def width(num_degrees, num_coords=3, append_identity=True):
  """Length of pos_enc / integrated_pos_enc over num_degrees degrees of num_coords coordinates."""
  return num_coords * (int(append_identity) + 2 * num_degrees)


def feature_layout(num_degrees, num_coords=3, append_identity=True, interleaved=False):
  """Index map of an encoding: (kind [L], degree [L], coord [L]) int; kind 0 id (deg -1), 1 sin, 2 cos.

  interleaved: NeRF's order (interleaved_pos_enc), else the released block order (pos_enc).
  """
  if interleaved:
    return _interleaved_layout(num_degrees, num_coords)
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
