"""DS-NeRF's sparse depth loss: the rendered depth of the rays through structure-from-motion points, pulled
towards the points' depths, each weighted by how well the point reprojects."""

import jax.numpy as jnp

from internal.losses.rendered import over_levels


def sparse_depth_loss(depth, target, weight):
  """Weighted mean squared error sum(w (d - t)^2) / sum(w); depth, target, weight [K] -> scalar.

  Rays with weight 0 or a target that is not finite carry no point; with none the loss is 0.
  """
  used = (weight > 0) & jnp.isfinite(target)
  error = jnp.where(used, depth - jnp.where(used, target, 0.), 0.)
  weight = jnp.where(used, weight, 0.)
  return jnp.sum(weight * error**2) / jnp.maximum(jnp.sum(weight), 1e-12)


def is_on(config) -> bool:
  """Whether Config asks for the sparse depth term (a capture's structure-from-motion points)."""
  return config.sfm_depth_loss_mult > 0


def term(config, rendered: dict, batch, step) -> tuple:
  """(Config.sfm_depth_loss_mult x the sparse depth loss of the rays through the points, summed over the levels as
  the data loss, {'loss_sfm_depth'}) (losses/terms.py)."""
  del step  # A constant weight.
  loss = over_levels(config, [sparse_depth_loss(t, batch.sfm_depth, batch.sfm_weight)
                              for t in rendered['sfm_rays'].depths()])
  return config.sfm_depth_loss_mult * loss, {'loss_sfm_depth': loss}
