"""Deterministic rendering of whole images in fixed-size chunks (one compile per chunk size)."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from internal import rays as rays_lib
from internal.models import freq_schedule
from internal.run import out_of_memory

OUTPUT_KEYS = ('rgb', 'acc', 'distance_mean', 'distance_median')


def compile_render(config, model, compute_normals: bool = False):
  """jit-compiled (params, masks, rays [N, ...]) -> fine-level outputs; masks = (point, view) frequency masks.

  The masks are an argument, so one compilation (per chunk size) serves every step.
  """
  padding = config.resample_padding_final
  keys = OUTPUT_KEYS + (('normals',) if compute_normals else ())

  @jax.jit
  def render(params, masks, chunk):
    renderings, _ = model.apply({'params': params}, None, chunk, *masks, padding, compute_normals=compute_normals)
    return {k: renderings[-1][k] for k in keys}
  return render


def make_render_fn(config, model, params, step: int, compute_normals: bool = False, compiled=None):
  """rays [N, ...] -> fine-level outputs, with the masks of the checkpoint step.

  compiled: a compile_render(config, model, compute_normals) to reuse (e.g. at every step of a learning curve).
  """
  compiled = compiled or compile_render(config, model, compute_normals)
  masks = freq_schedule.model_masks(config, model, jnp.asarray(step))
  # Parameters are an argument, not constants folded into the compiled program.
  return functools.partial(compiled, params, masks)


def render_image(render_fn, rays, chunk_size: int):
  """Renders Rays with [H, W, ...] fields chunk by chunk; returns numpy outputs [H, W, ...]."""
  shape = rays.origins.shape[:-1]
  flat = rays_lib.map_rays(lambda x: np.reshape(x, (-1, x.shape[-1])), rays)
  num_rays = flat.origins.shape[0]
  pad = (-num_rays) % chunk_size if num_rays > chunk_size else 0
  padded = rays_lib.map_rays(lambda x: np.pad(x, ((0, pad), (0, 0)), mode='edge'), flat)
  size = min(chunk_size, num_rays)
  with out_of_memory.naming_setting('rendering', f'Config.render_chunk_size = {chunk_size} (rays rendered at once)'):
    pieces = [jax.device_get(render_fn(rays_lib.map_rays(functools.partial(_slice, i, size), padded)))
              for i in range(0, num_rays + pad, size)]
  return {k: np.concatenate([p[k] for p in pieces])[:num_rays].reshape(shape + pieces[0][k].shape[1:])
          for k in pieces[0]}


def _slice(start, size, x):
  """Rows start:start+size of x."""
  return x[start:start + size]
