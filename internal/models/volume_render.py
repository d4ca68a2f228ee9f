"""Volume rendering of per-sample colours and densities along rays: mip-NeRF's intervals, NeRF's points."""

import jax
import jax.numpy as jnp

PERCENTILES = (5., 25., 50., 75., 95.)


OPEN_INTERVAL = 1e10  # NeRF's length of the last sample's interval: it absorbs whatever is left of the ray.


def compute_weights(density, t_vals, directions):
  """Alpha-compositing weights [B,S] from density [B,S], t_vals [B,S+1], directions [B,3]."""
  return weights_of_deltas(density, t_vals[..., 1:] - t_vals[..., :-1], directions)


def weights_of_deltas(density, deltas, directions):
  """Alpha-compositing weights [B,S] from density [B,S] over intervals of lengths deltas [B,S] (in t)."""
  delta = deltas * jnp.linalg.norm(directions[..., None, :], axis=-1)
  density_delta = density * delta
  alpha = -jnp.expm1(-density_delta)
  zeros = jnp.zeros_like(density_delta[..., :1])
  trans = jnp.exp(-jnp.concatenate([zeros, jnp.cumsum(density_delta[..., :-1], axis=-1)], axis=-1))
  return alpha * trans


def _safe_div(num, den):
  """num / den where den > 0, else 0 (finite gradients); same shape."""
  return jnp.where(den > 0, num / jnp.where(den > 0, den, 1.), 0.)


def weighted_percentiles(weights, t_mids, percentiles):
  """Percentiles [B,P]: levels p*acc interpolated in the cumulative weights [B,S] against positions t_mids [B,S].

  This is the released weighted percentile (docs/numerics.md): at acc = 0 every cumulative weight is 0
  and the result is the second-to-last position.
  """
  cum = jnp.cumsum(weights, axis=-1)
  levels = jnp.asarray(percentiles, jnp.float32) / 100. * cum[..., -1:]
  batch = weights.shape[:-1]
  flat = jax.vmap(jnp.interp)(levels.reshape(-1, len(percentiles)), cum.reshape(-1, cum.shape[-1]),
                           t_mids.reshape(-1, t_mids.shape[-1]))
  return flat.reshape(batch + (len(percentiles),))


def volumetric_rendering(rgb, density, t_vals, directions, white_background, compute_extras=False):
  """Renders rgb [B,S,3], density [B,S] over t_vals [B,S+1] (mip-NeRF's intervals) -> dict of [B,...] arrays.

  Keys: rgb, acc, weights, distance_mean, distance_median; with compute_extras also distance_percentiles and
  distance_std.
  """
  weights = compute_weights(density, t_vals, directions)
  t_mids = 0.5 * (t_vals[..., :-1] + t_vals[..., 1:])
  return composite(rgb, weights, t_mids, (t_vals[..., 0], t_vals[..., -1]), white_background, compute_extras)


def point_rendering(rgb, density, t_points, directions, white_background, compute_extras=False):
  """Renders rgb [B,S,3], density [B,S] at sample points t_points [B,S] (NeRF's quadrature) -> dict as above.

  Sample i covers [t_i, t_i+1), the last one an OPEN_INTERVAL; distances are taken at the points themselves.
  """
  deltas = jnp.concatenate([t_points[..., 1:] - t_points[..., :-1],
                            jnp.full_like(t_points[..., :1], OPEN_INTERVAL)], axis=-1)
  weights = weights_of_deltas(density, deltas, directions)
  return composite(rgb, weights, t_points, (t_points[..., 0], t_points[..., -1]), white_background,
                   compute_extras)


def composite(rgb, weights, t_positions, t_range, white_background, compute_extras):
  """Composites rgb [B,S,3] with weights [B,S] at distances t_positions [B,S] in t_range ([B], [B])."""
  acc = jnp.sum(weights, axis=-1)
  comp_rgb = jnp.sum(weights[..., None] * rgb, axis=-2)
  if white_background:
    comp_rgb = comp_rgb + (1. - acc[..., None])
  mean = _safe_div(jnp.sum(weights * t_positions, axis=-1), acc)
  # Where acc = 0 the released code's nan_to_num gives 0, which the clip turns into near.
  distance_mean = jnp.clip(mean, *t_range)
  percentiles = weighted_percentiles(weights, t_positions, PERCENTILES)
  out = {'rgb': comp_rgb, 'acc': acc, 'weights': weights, 'distance_mean': distance_mean,
         'distance_median': percentiles[..., PERCENTILES.index(50.)]}
  if compute_extras:
    var = _safe_div(jnp.sum(weights * (t_positions - mean[..., None])**2, axis=-1), acc)
    out['distance_percentiles'] = percentiles
    out['distance_std'] = jnp.where(var > 0, jnp.sqrt(jnp.where(var > 0, var, 1.)), 0.)
  return out
