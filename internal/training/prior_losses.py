"""The depth-prior terms of the training loss: ranking and Pearson on patches of the training views, DS-NeRF's
sparse depth on the rays through structure-from-motion points (internal/datasets/batching.make_prior_sampler).

Each term renders its own rays with the step's masks and sums its loss over the levels, the coarse ones weighted
by Config.coarse_loss_mult as the data loss.
"""

import jax
import jax.numpy as jnp
from jax import random

from internal.datasets import depth_prior
from internal.datasets import loader
from internal.losses import depth_pearson
from internal.losses import depth_ranking
from internal.losses import sparse_depth
from internal.training import anneal
from internal.training import schedule

# Salts of the sampling keys of the prior rays (RegNeRF's patches use 1).
PATCH_SALT, SFM_SALT = 2, 3
NDC_FAR_EPS = 1e-3  # NDC t near 1 is depth near infinity: depth = 1 / max(1 - t, this).


def any_on(config) -> bool:
  """Whether a depth-prior loss is on."""
  return depth_prior.dense_losses_on(config) or config.sfm_depth_loss_mult > 0


def _level_depths(config, model, params, rays, key, step, masks):
  """Rendered t [L, ...] of rays [..., C] (anything before C is kept) per level."""
  shape = rays.origins.shape[:-1]
  flat = jax.tree.map(lambda x: x.reshape((-1, x.shape[-1])), rays)
  if config.anneal_nearfar:
    flat = anneal.anneal_rays(config, flat, step)
  renderings, _ = model.apply({'params': params}, key if config.randomized else None, flat, *masks,
                              schedule.resample_padding(config, step))
  return [r['distance_mean'].reshape(shape) for r in renderings]


def _over_levels(config, values) -> jax.Array:
  """sum of per-level values, the coarse ones times Config.coarse_loss_mult."""
  return values[-1] + config.coarse_loss_mult * sum(values[:-1])


def pearson_values(t, kind: str, ndc: bool):
  """What a prior of kind ('depth' | 'disparity') is correlated with: the rendered depth or disparity of t [...]
  (NDC t is affine in disparity: 1 - t)."""
  if ndc:
    return 1. - t if kind == 'disparity' else 1. / jnp.maximum(1. - t, NDC_FAR_EPS)
  return 1. / t if kind == 'disparity' else t


def loss_terms(config, model, params, batch, key, step, masks) -> tuple:
  """(weighted sum to add to the loss, stats {'loss_depth_rank', 'loss_depth_pearson', 'loss_sfm_depth'} of the
  terms that are on); masks: the step's (point, view) frequency masks."""
  stats, total = {}, 0.
  if depth_prior.dense_losses_on(config):
    depths = _level_depths(config, model, params, batch['prior_rays'], random.fold_in(key, PATCH_SALT), step, masks)
    disparity = config.depth_prior_kind == 'disparity'
    if config.depth_rank_loss_mult > 0:
      stats['loss_depth_rank'] = _over_levels(config, [depth_ranking.ranking_loss(
          t, batch['prior'], config.depth_rank_margin, disparity) for t in depths])
      total += config.depth_rank_loss_mult * stats['loss_depth_rank']
    if config.depth_pearson_loss_mult > 0:
      ndc = bool(loader.ndc(config))
      stats['loss_depth_pearson'] = _over_levels(config, [depth_pearson.pearson_loss(
          pearson_values(t, config.depth_prior_kind, ndc), batch['prior']) for t in depths])
      total += config.depth_pearson_loss_mult * stats['loss_depth_pearson']
  if config.sfm_depth_loss_mult > 0:
    depths = _level_depths(config, model, params, batch['sfm_rays'], random.fold_in(key, SFM_SALT), step, masks)
    stats['loss_sfm_depth'] = _over_levels(config, [sparse_depth.sparse_depth_loss(
        t, batch['sfm_depth'], batch['sfm_weight']) for t in depths])
    total += config.sfm_depth_loss_mult * stats['loss_sfm_depth']
  return total, stats
