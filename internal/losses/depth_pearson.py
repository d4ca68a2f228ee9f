"""The scale- and shift-invariant depth loss of FSGS and SparseGS: 1 - Pearson correlation per patch.

A monocular prior is an unknown affine map of the truth (of the depth, or of the disparity for disparity-like
models), which Pearson's correlation ignores; so each patch is scored by how far its rendered values are from
being an increasing affine function of the prior's.
"""

import jax.numpy as jnp

from internal.losses import depth_ranking

EPS = 1e-12  # Keeps the correlation's gradient finite where the rendered patch is flat (a rendered variance).
FLAT = 1e-6  # A patch whose prior varies by less than this, relative to its size, is flat: it says nothing.


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
