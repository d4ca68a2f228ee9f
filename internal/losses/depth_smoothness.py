"""RegNeRF's depth-smoothness regularizer: total variation of the expected depth of random-pose patches."""

import jax
import jax.numpy as jnp

from internal.datasets import random_poses


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


def linear(step, maxstep: int, start: float, end: float):
  """start (1 - w) + end w, w = clip(step / maxstep, 0, 1)."""
  w = jnp.clip(step / maxstep, 0., 1.)
  return start * (1. - w) + end * w


def tv_weight(config, step):
  """RegNeRF's depth-smoothness weight of the last level at step: decayed under Config.depth_tvnorm_decay."""
  if config.depth_tvnorm_decay:
    return linear(step, config.depth_tvnorm_maxstep, config.depth_tvnorm_loss_mult_start,
                  config.depth_tvnorm_loss_mult_end)
  return config.depth_tvnorm_loss_mult


def is_on(config) -> bool:
  """Whether Config asks for depth smoothness (random_poses.needs_patches: the batch then holds the patches)."""
  return random_poses.needs_patches(config)


def term(config, rendered: dict, batch, step) -> tuple:
  """(the depth TV of RegNeRF's random-pose patches over the levels, {'depth_tv_level<l>', 'loss_depth_tv'})
  (losses/terms.py): as released, the coarse levels weighted by Config.coarse_loss_mult, the last by tv_weight."""
  del batch  # The rendered patches only.
  patches = rendered['patch_rays']
  tvs = jnp.stack([patch_depth_tv(level['weights'], level['t_vals'], patches.shape, config.depth_tvnorm_mask_weight,
                                  config.regnerf_fix_released_bugs) for level in patches.history])
  stats = {f'depth_tv_level{level}': tv for level, tv in enumerate(tvs)}
  level_mults = [config.coarse_loss_mult] * (len(tvs) - 1) + [tv_weight(config, step)]
  stats['loss_depth_tv'] = sum(mult * tv for mult, tv in zip(level_mults, tvs))
  return stats['loss_depth_tv'], stats
