"""RegNeRF's sample-space annealing: [near, far] grows from a band around a mid point to the full range."""

import jax.numpy as jnp


def near_far(step, near, far, n_steps: int, init_perc: float, mid_perc: float):
  """(near, far) at step: mid = near + mid_perc (far - near), start mid + init_perc (x - mid), linear over n_steps."""
  mid = near + mid_perc * (far - near)
  near_init, far_init = mid + init_perc * (near - mid), mid + init_perc * (far - mid)
  w = jnp.minimum(step / n_steps, 1.)
  return near_init + w * (near - near_init), far_init + w * (far - far_init)


def anneal_rays(config, rays, step):
  """Rays [..., 1] with their own near/far annealed at a (possibly traced) step. The rays' bounds, not Config.near/far:
  they are equal on DTU and LLFF, but a capture's loader finds its own (Config.near/far of 2 and 6 would leave a cup
  1 unit from the camera unsampled all through training)."""
  near, far = near_far(step, rays.near, rays.far, config.anneal_nearfar_steps, config.anneal_nearfar_perc,
                       config.anneal_mid_perc)
  return rays._replace(near=near, far=far)
