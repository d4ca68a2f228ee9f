"""SparseNeRF's local depth-ranking loss: inside a patch, the rendered depths keep the order of the prior's.

A monocular prior is right about which of two nearby pixels is nearer far more often than about how far either
is, and its unknown scale and shift leave that order unchanged; so for every pair of pixels of a patch that the
prior orders (nearer i, farther j) the loss is the hinge max(0, d_i - d_j + margin) on the rendered depths d.
"""

import jax.numpy as jnp

from internal.losses.rendered import over_levels


def prior_mask(prior):
  """Where a prior [...] holds a value: finite and nonzero (0 and non-finite values are "no prior")."""
  return jnp.isfinite(prior) & (prior != 0)


def ranking_loss(depth, prior, margin: float, disparity: bool):
  """Mean hinge over the ordered pixel pairs of each patch; depth [P, n] rendered, prior [P, n] -> scalar.

  disparity: the prior grows towards the camera (disparity-like), else with depth. Pairs the prior cannot order
  (a pixel without prior, equal values) are left out; with none left the loss is 0.
  """
  valid = prior_mask(prior)
  key = jnp.where(valid, -prior if disparity else prior, 0.)
  nearer = valid[:, :, None] & valid[:, None, :] & (key[:, :, None] < key[:, None, :])
  hinge = jnp.maximum(depth[:, :, None] - depth[:, None, :] + margin, 0.)
  return jnp.sum(jnp.where(nearer, hinge, 0.)) / jnp.maximum(jnp.sum(nearer), 1)


def is_on(config) -> bool:
  """Whether Config asks for the ranking term (a dense depth prior)."""
  return config.depth_rank_loss_mult > 0


def term(config, rendered: dict, batch, step) -> tuple:
  """(Config.depth_rank_loss_mult x the ranking loss of the depth-prior patches' rendered t against the prior, summed
  over the levels as the data loss, {'loss_depth_rank'}) (losses/terms.py)."""
  del step  # A constant weight.
  disparity = config.depth_prior_kind == 'disparity'
  loss = over_levels(config, [ranking_loss(t, batch.prior, config.depth_rank_margin, disparity)
                              for t in rendered['prior_rays'].depths()])
  return config.depth_rank_loss_mult * loss, {'loss_depth_rank': loss}
