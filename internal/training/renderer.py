"""The one renderer of a training step: every ray family of the batch (datasets/batching.FAMILIES) rendered once by
the model at the step's frequency masks and resampling padding, near and far annealed where Config asks (RegNeRF),
each family with its own sampling key: the step's own for the training pixels (the first family), else the step's
folded with the family's position in FAMILIES; the loss terms read the renderings (losses/terms.py)."""

import jax
from jax import random

from internal.datasets import batching
from internal.losses.rendered import Rendered
from internal.training import anneal
from internal.training import schedule


def render(config, model, params, rays, key, step, masks) -> Rendered:
  """The model's renderings of rays [..., C] (flattened to [R, C]) at step; masks: the (point, view) frequency
  masks; key: the sampling key (unused unless Config.randomized)."""
  flat = jax.tree.map(lambda x: x.reshape((-1, x.shape[-1])), rays)
  if config.anneal_nearfar:
    flat = anneal.anneal_rays(config, flat, step)
  levels, history = model.apply({'params': params}, key if config.randomized else None, flat, *masks,
                                schedule.resample_padding(config, step))
  return Rendered(flat, levels, history, rays.origins.shape[:-1])


def render_batch(config, model, params, batch: batching.Batch, key, step, masks) -> dict:
  """{Batch field: Rendered} of every ray family batch holds."""
  out = {}
  for salt, (name, _) in enumerate(batching.FAMILIES):
    rays = getattr(batch, name)
    if rays is not None:
      out[name] = render(config, model, params, rays, random.fold_in(key, salt) if salt else key, step, masks)
  return out
