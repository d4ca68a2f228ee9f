"""RegNeRF's depth-smoothness regularizer: total variation of the expected depth of random-pose patches."""

import jax
import jax.numpy as jnp


def expected_depth(weights, t_vals):
  """Expected depth [...] of weights [..., S] over t_vals [..., S+1], acc clamped to eps, clipped to [t0, tS]."""
  t_mids = 0.5 * (t_vals[..., 1:] + t_vals[..., :-1])
  acc = jnp.sum(weights, axis=-1)
  depth = jnp.sum(weights * t_mids, axis=-1) / jnp.maximum(acc, jnp.finfo(jnp.float32).eps)
  return jnp.clip(depth, t_vals[..., 0], t_vals[..., -1])


def tv_norm(depth, weighting):
  """Mean over [P, ps-1, ps-1] of weighting * ((d[i,j] - d[i,j+1])^2 + (d[i,j] - d[i+1,j])^2), depth [P, ps, ps]."""
  d00 = depth[:, :-1, :-1]
  tv = (d00 - depth[:, :-1, 1:])**2 + (d00 - depth[:, 1:, :-1])**2
  return jnp.mean(tv * weighting)


def tv_weighting(acc, mask_weight: float, fix: bool):
  """Weights [P, ps-1, ps-1] from patch opacity acc [P, ps, ps]: stop_grad(acc) * mask_weight.

  Released: mask_weight 0 zeroes the loss (RegNeRF's LLFF configs). fix: mask_weight 0 means unweighted.
  """
  if fix and mask_weight == 0:
    return jnp.ones_like(acc[:, :-1, :-1])
  return jax.lax.stop_gradient(acc[:, :-1, :-1]) * mask_weight


def patch_depth_tv(weights, t_vals, patch_shape, mask_weight: float, fix: bool):
  """Unweighted TV of one level's expected depth, weights [P*ps*ps, S], t_vals [P*ps*ps, S+1] -> scalar.

  patch_shape: (P, ps, ps); mask_weight and fix as in tv_weighting.
  """
  depth = expected_depth(weights, t_vals).reshape(patch_shape)
  acc = jnp.sum(weights, axis=-1).reshape(patch_shape)
  return tv_norm(depth, tv_weighting(acc, mask_weight, fix))
