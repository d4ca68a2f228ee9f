"""Volume rendering of per-sample colours and densities along rays (mip-NeRF quadrature)."""

import jax.numpy as jnp

from internal import sampling

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
  """Percentiles [B,P] of the step pdf (weights [B,S] over t_vals [B,S+1]); t_last when weights are 0."""
  acc = jnp.sum(weights, axis=-1, keepdims=True)
  cdf = jnp.minimum(1., _safe_div(jnp.cumsum(weights, axis=-1), acc))
  cdf = jnp.concatenate([jnp.zeros_like(acc), cdf], axis=-1)
  u = jnp.broadcast_to(jnp.asarray(percentiles, jnp.float32) / 100., acc.shape[:-1] + (len(percentiles),))
  values = sampling.invert_cdf(u, cdf, t_vals)
  return jnp.where(acc > 0, values, t_vals[..., -1:])


def volumetric_rendering(rgb, density, t_vals, directions, white_background, compute_extras=False):
  """Renders rgb [B,S,3], density [B,S] over t_vals [B,S+1] -> dict (see INTERFACES.md)."""
  weights = compute_weights(density, t_vals, directions)
  acc = jnp.sum(weights, axis=-1)
  comp_rgb = jnp.sum(weights[..., None] * rgb, axis=-2)
  if white_background:
    comp_rgb = comp_rgb + (1. - acc[..., None])
  t_mids = 0.5 * (t_vals[..., :-1] + t_vals[..., 1:])
  mean = _safe_div(jnp.sum(weights * t_mids, axis=-1), acc)
  distance_mean = jnp.clip(jnp.where(acc > 0, mean, jnp.inf), t_vals[..., 0], t_vals[..., -1])
  percentiles = weighted_percentiles(weights, t_vals, PERCENTILES)
  out = {'rgb': comp_rgb, 'acc': acc, 'weights': weights, 'distance_mean': distance_mean,
         'distance_median': percentiles[..., PERCENTILES.index(50.)]}
  if compute_extras:
    var = _safe_div(jnp.sum(weights * (t_mids - mean[..., None])**2, axis=-1), acc)
    out['distance_percentiles'] = percentiles
    out['distance_std'] = jnp.where(var > 0, jnp.sqrt(jnp.where(var > 0, var, 1.)), 0.)
  return out
