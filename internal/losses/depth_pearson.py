"""The scale- and shift-invariant depth loss of FSGS and SparseGS: 1 - Pearson correlation per patch.

A monocular prior is an unknown affine map of the truth (of the depth, or of the disparity for disparity-like
models), which Pearson's correlation ignores; so each patch is scored by how far its rendered values are from
being an increasing affine function of the prior's.
"""

import jax.numpy as jnp

from internal.datasets import loader
from internal.losses import depth_ranking
from internal.losses.rendered import over_levels

EPS = 1e-12  # Keeps the correlation's gradient finite where the rendered patch is flat (a rendered variance).
FLAT = 1e-6  # A patch whose prior varies by less than this, relative to its size, is flat: it says nothing.
NDC_FAR_EPS = 1e-3  # NDC t near 1 is depth near infinity: depth = 1 / max(1 - t, this).


def pearson_loss(rendered, prior):
  """Mean over informative patches of 1 - corr(rendered, prior) over their valid pixels; [P, n] each -> scalar.

  A patch informs when it has 2 or more pixels with a prior that is not flat; with none the loss is 0.
  rendered: depth for a depth-like prior, disparity for a disparity-like one.
  """
  valid = depth_ranking.prior_mask(prior)
  count = jnp.sum(valid, axis=-1)
  safe = jnp.maximum(count, 1)
  prior = jnp.where(valid, prior, 0.)
  centred = lambda x: jnp.where(valid, x - (jnp.sum(jnp.where(valid, x, 0.), -1) / safe)[:, None], 0.)
  r, p = centred(rendered), centred(prior)
  var_r, var_p = jnp.sum(r * r, -1) / safe, jnp.sum(p * p, -1) / safe
  informs = (count >= 2) & (var_p > (FLAT * jnp.max(jnp.abs(prior), axis=-1))**2)
  p = p / jnp.sqrt(jnp.where(informs, var_p, 1.))[:, None]  # The prior in its own units: any scale works.
  corr = jnp.sum(r * p, -1) / safe / jnp.sqrt(var_r + EPS)
  return jnp.sum(jnp.where(informs, 1. - corr, 0.)) / jnp.maximum(jnp.sum(informs), 1)


def pearson_values(t, kind: str, ndc: bool):
  """What a prior of kind ('depth' | 'disparity') is correlated with: the rendered depth or disparity of t [...]
  (NDC t is affine in disparity: 1 - t)."""
  if ndc:
    return 1. - t if kind == 'disparity' else 1. / jnp.maximum(1. - t, NDC_FAR_EPS)
  return 1. / t if kind == 'disparity' else t


def is_on(config) -> bool:
  """Whether Config asks for the Pearson term (a dense depth prior)."""
  return config.depth_pearson_loss_mult > 0


def term(config, rendered: dict, batch, step) -> tuple:
  """(Config.depth_pearson_loss_mult x the Pearson loss of the depth-prior patches' rendered depth or disparity
  against the prior, summed over the levels as the data loss, {'loss_depth_pearson'}) (losses/terms.py)."""
  del step  # A constant weight.
  ndc = bool(loader.ndc(config))
  loss = over_levels(config, [pearson_loss(pearson_values(t, config.depth_prior_kind, ndc), batch.prior)
                              for t in rendered['prior_rays'].depths()])
  return config.depth_pearson_loss_mult * loss, {'loss_depth_pearson': loss}
