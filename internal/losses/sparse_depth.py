"""DS-NeRF's sparse depth loss: the rendered depth of the rays through structure-from-motion points, pulled
towards the points' depths, each weighted by how well the point reprojects."""

import jax.numpy as jnp


def sparse_depth_loss(depth, target, weight):
  """Weighted mean squared error sum(w (d - t)^2) / sum(w); depth, target, weight [K] -> scalar.

  Rays with weight 0 or a target that is not finite carry no point; with none the loss is 0.
  """
  used = (weight > 0) & jnp.isfinite(target)
  error = jnp.where(used, depth - jnp.where(used, target, 0.), 0.)
  weight = jnp.where(used, weight, 0.)
  return jnp.sum(weight * error**2) / jnp.maximum(jnp.sum(weight), 1e-12)
