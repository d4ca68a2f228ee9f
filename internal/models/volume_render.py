"""Volume rendering of per-sample colours and densities along rays (mip-NeRF quadrature)."""

import jax
import jax.numpy as jnp

PERCENTILES = (5., 25., 50., 75., 95.)


def compute_weights(density, t_vals, directions):
  """Alpha-compositing weights [B,S] from density [B,S], t_vals [B,S+1], directions [B,3]."""
  delta = (t_vals[..., 1:] - t_vals[..., :-1]) * jnp.linalg.norm(directions[..., None, :], axis=-1)
  density_delta = density * delta
  alpha = -jnp.expm1(-density_delta)
  zeros = jnp.zeros_like(density_delta[..., :1])
  trans = jnp.exp(-jnp.concatenate([zeros, jnp.cumsum(density_delta[..., :-1], axis=-1)], axis=-1))
  return alpha * trans


def _safe_div(num, den):
  """num / den where den > 0, else 0 (finite gradients); same shape."""
  return jnp.where(den > 0, num / jnp.where(den > 0, den, 1.), 0.)


def weighted_percentiles(weights, t_vals, percentiles):
  """Percentiles [B,P]: levels p*acc interpolated in the cumulative weights [B,S] against the midpoints.

  This is the released weighted percentile (docs/numerics.md): at acc = 0 every cumulative weight is 0
  and the result is the second-to-last midpoint.
  """
  t_mids = 0.5 * (t_vals[..., :-1] + t_vals[..., 1:])
  cum = jnp.cumsum(weights, axis=-1)
  levels = jnp.asarray(percentiles, jnp.float32) / 100. * cum[..., -1:]
  batch = weights.shape[:-1]
  flat = jax.vmap(jnp.interp)(levels.reshape(-1, len(percentiles)), cum.reshape(-1, cum.shape[-1]),
                           t_mids.reshape(-1, t_mids.shape[-1]))
  return flat.reshape(batch + (len(percentiles),))


def volumetric_rendering(rgb, density, t_vals, directions, white_background, compute_extras=False):
  """Renders rgb [B,S,3], density [B,S] over t_vals [B,S+1] -> dict of [B,...] arrays.

  Keys: rgb, acc, weights, distance_mean, distance_median; with compute_extras also distance_percentiles and
  distance_std.
  """
  weights = compute_weights(density, t_vals, directions)
  acc = jnp.sum(weights, axis=-1)
  comp_rgb = jnp.sum(weights[..., None] * rgb, axis=-2)
  if white_background:
    comp_rgb = comp_rgb + (1. - acc[..., None])
  t_mids = 0.5 * (t_vals[..., :-1] + t_vals[..., 1:])
  mean = _safe_div(jnp.sum(weights * t_mids, axis=-1), acc)
  # Where acc = 0 the released code's nan_to_num gives 0, which the clip turns into near.
  distance_mean = jnp.clip(mean, t_vals[..., 0], t_vals[..., -1])
  percentiles = weighted_percentiles(weights, t_vals, PERCENTILES)
  out = {'rgb': comp_rgb, 'acc': acc, 'weights': weights, 'distance_mean': distance_mean,
         'distance_median': percentiles[..., PERCENTILES.index(50.)]}
  if compute_extras:
    var = _safe_div(jnp.sum(weights * (t_mids - mean[..., None])**2, axis=-1), acc)
    out['distance_percentiles'] = percentiles
    out['distance_std'] = jnp.where(var > 0, jnp.sqrt(jnp.where(var > 0, var, 1.)), 0.)
  return out
