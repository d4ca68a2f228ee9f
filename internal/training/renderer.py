"""The one renderer of a training step: every ray family of the batch (datasets/batching.FAMILIES) rendered once by
the model at the step's frequency masks and resampling padding, near and far annealed where Config asks (RegNeRF),
each family with its own sampling key; the loss terms read the renderings (losses/terms.py)."""

from jax import random

import jax

from internal.losses.rendered import Rendered
from internal.training import anneal
from internal.training import schedule

# The sampling key of each family: the step's own for the training pixels, else folded with a salt.
SALTS = {'rays': None, 'patch_rays': 1, 'prior_rays': 2, 'sfm_rays': 3}


def render(config, model, params, rays, key, step, masks) -> Rendered:
  """The model's renderings of rays [..., C] (flattened to [R, C]) at step; masks: the (point, view) frequency
  masks; key: the sampling key (unused unless Config.randomized)."""
  flat = jax.tree.map(lambda x: x.reshape((-1, x.shape[-1])), rays)
  if config.anneal_nearfar:
    flat = anneal.anneal_rays(config, flat, step)
  levels, history = model.apply({'params': params}, key if config.randomized else None, flat, *masks,
                                schedule.resample_padding(config, step))
  return Rendered(flat, levels, history, rays.origins.shape[:-1])


def render_batch(config, model, params, batch, key, step, masks) -> dict:
  """{Batch field: Rendered} of every ray family batch holds."""
  families = {name: getattr(batch, name) for name in SALTS if getattr(batch, name) is not None}
  return {name: render(config, model, params, rays, key if SALTS[name] is None else random.fold_in(key, SALTS[name]),
                       step, masks) for name, rays in families.items()}
