"""A released-equivalent MLP for benchmarking: per-sample vmap(value_and_grad) density and tiled masks.

The released code evaluates the trunk one sample at a time under vmap(value_and_grad(...)) to get
normals on every call, and tiles the frequency masks to [B, S, L]. This module reproduces that graph
structure on our parameter tree so the two can be timed side by side.
"""

import jax
import jax.numpy as jnp
from jax import random

from internal import encoding
from internal import models


def _dense(layer, x):
  """x [..., I] @ kernel [I, O] + bias."""
  return x @ layer['kernel'] + layer['bias']


class ReleasedMLP(models.MLP):
  """Same parameters as MLP; the graph the released code builds (normals sown, not returned)."""

  def __call__(self, key, means, covs, viewdirs, mask_point, mask_view):
    """rgb [B, S, 3], density [B, S]; per-sample normals sown into 'intermediates'."""
    params = self.variables['params']
    batch_shape = means.shape[:-1]
    num = means.reshape(-1, 3).shape[0]
    mask_point = jnp.tile(jnp.ones(99) if mask_point is None else mask_point, (num, 1))
    noise = 0. if key is None else self.density_noise * random.normal(key, ())

    def density_one(mean, cov, mask):
      x = encoding.integrated_pos_enc(mean, cov, self.min_deg_point, self.max_deg_point) * mask
      inputs = x
      for i in range(self.net_depth):
        x = self.net_activation(_dense(params[f'Dense_{i}'], x))
        if i % self.skip_layer == 0 and i > 0:
          x = jnp.concatenate([x, inputs], axis=-1)
      raw = _dense(params[f'Dense_{self.net_depth}'], x)[0] + noise
      return self.density_activation(raw + self.density_bias), x

    (density, x), grad = jax.vmap(jax.value_and_grad(density_one, has_aux=True))(
        means.reshape(-1, 3), covs.reshape(-1, 3), mask_point)
    self.sow('intermediates', 'normals', -grad / jnp.maximum(
        jnp.linalg.norm(grad, axis=-1, keepdims=True), 1e-7))
    x = _dense(params[f'Dense_{self.net_depth + 1}'], x)
    view = encoding.pos_enc(viewdirs, 0, self.deg_view, append_identity=True)
    view = jnp.broadcast_to(view[:, None], batch_shape + view.shape[-1:]).reshape(num, -1)
    view = view * jnp.tile(jnp.ones(view.shape[-1]) if mask_view is None else mask_view, (num, 1))
    x = self.net_activation(_dense(params[f'Dense_{self.net_depth + 2}'], jnp.concatenate([x, view], -1)))
    rgb = self.rgb_activation(_dense(params[f'Dense_{self.net_depth + 3}'], x))
    rgb = rgb * (1 + 2 * self.rgb_padding) - self.rgb_padding
    return rgb.reshape(batch_shape + (3,)), density.reshape(batch_shape)


class ReleasedModel(models.MipNerfModel):
  """MipNerfModel whose shared MLP is the released-equivalent one."""

  def setup(self):
    self.mlp = ReleasedMLP()
