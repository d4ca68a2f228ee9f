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


def loss_weight(step, maxstep: int, start: float, end: float):
  """Schedule start (1 - w) + end w, w = clip(step / maxstep, 0, 1)."""
  w = jnp.clip(step / maxstep, 0., 1.)
  return start * (1. - w) + end * w


def tv_weighting(acc, mask_weight: float, fix: bool):
  """Weights [P, ps-1, ps-1] from patch opacity acc [P, ps, ps]: stop_grad(acc) * mask_weight.

  Released: mask_weight 0 zeroes the loss (RegNeRF's LLFF configs). fix: mask_weight 0 means unweighted.
  """
  if fix and mask_weight == 0:
    return jnp.ones_like(acc[:, :-1, :-1])
  return jax.lax.stop_gradient(acc[:, :-1, :-1]) * mask_weight


def level_weights(config, step, num_levels: int):
  """Multiplier of each level's TV: coarse_loss_mult below the last, the (scheduled) TV mult on the last."""
  last = (loss_weight(step, config.depth_tvnorm_maxstep, config.depth_tvnorm_loss_mult_start,
                      config.depth_tvnorm_loss_mult_end) if config.depth_tvnorm_decay
          else config.depth_tvnorm_loss_mult)
  return [config.coarse_loss_mult] * (num_levels - 1) + [last]


def depth_smoothness_loss(config, history, patch_shape, step):
  """(weighted total, per-level TV [L]) of the ray history of patch rays rendered as [P * ps * ps]."""
  tvs = []
  for level in history:
    depth = expected_depth(level['weights'], level['t_vals']).reshape(patch_shape)
    acc = jnp.sum(level['weights'], axis=-1).reshape(patch_shape)
    tvs.append(tv_norm(depth, tv_weighting(acc, config.depth_tvnorm_mask_weight,
                                           config.regnerf_fix_released_bugs)))
  total = sum(w * tv for w, tv in zip(level_weights(config, step, len(tvs)), tvs))
  return total, jnp.stack(tvs)
