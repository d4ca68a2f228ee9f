"""A released-equivalent MLP for benchmarking: per-sample vmap(value_and_grad) density and tiled masks.

The released code evaluates the trunk one sample at a time under vmap(value_and_grad(...)) to get
normals on every call, and tiles the frequency masks to [B, S, L]. This module reproduces that graph
structure on our parameter tree so the two can be timed side by side.
"""

import dataclasses

import jax
import flax.linen as nn
import jax.numpy as jnp

from internal.models import encoding
from internal.models import dense
from internal.models import mip_nerf


class ReleasedMLP(mip_nerf.MLP):
  """Same parameters as MLP; the graph the released code builds (normals sown, not returned)."""

  def __call__(self, key, means, covs, viewdirs, mask_point, mask_view):
    """rgb [B, S, 3], density [B, S]; per-sample normals sown into 'intermediates'."""
    num = means.shape[0] * means.shape[1]
    tile = lambda mask, length: jnp.tile(jnp.ones(length) if mask is None else mask, (num, 1))
    noise = self._noise(key, ())  # The released single draw per batch.

    def density_one(mean, cov, mask):
      """Released trunk on one sample: concatenated skip input, density and features."""
      x = enc = encoding.integrated_pos_enc(mean, cov, self.min_deg_point, self.max_deg_point) * mask
      for i in range(self.net_depth):
        x = self.net_activation(dense.dense(self.layers[f'Dense_{i}'], x))
        if self._skip_after(i):
          x = jnp.concatenate([x, enc], axis=-1)
      raw = dense.dense(self.layers[f'Dense_{self.net_depth}'], x)[0] + noise
      return self.density_activation(raw + self.density_bias), x

    (density, x), grad = jax.vmap(jax.value_and_grad(density_one, has_aux=True))(
        means.reshape(-1, 3), covs.reshape(-1, 3), tile(mask_point, encoding.width(self.encoding_degrees()[0])))
    self.sow('intermediates', 'normals', -grad / jnp.maximum(
        jnp.linalg.norm(grad, axis=-1, keepdims=True), 1e-7))
    view = encoding.pos_enc(viewdirs, 0, self.deg_view, append_identity=True)
    view = jnp.broadcast_to(view[:, None], means.shape[:-1] + view.shape[-1:]).reshape(num, -1)
    x = dense.dense(self.layers[f'Dense_{self.net_depth + 1}'], x)
    x = jnp.concatenate([x, view * tile(mask_view, view.shape[-1])], axis=-1)
    x = self.net_activation(dense.dense(self.layers[f'Dense_{self.net_depth + 2}'], x))
    rgb = self.rgb_activation(dense.dense(self.layers[f'Dense_{self.net_depth + 3}'], x))
    rgb = rgb * (1 + 2 * self.rgb_padding) - self.rgb_padding
    return rgb.reshape(means.shape), density.reshape(means.shape[:-1])


def released_mlp(mlp: mip_nerf.MLP) -> ReleasedMLP:
  """The released-equivalent graph with every setting of mlp (its gin bindings and precision)."""
  return ReleasedMLP(**{f.name: getattr(mlp, f.name) for f in dataclasses.fields(mlp)
                        if f.name not in ('parent', 'name')})


class ReleasedModel(mip_nerf.MipNerfModel):
  """MipNerfModel whose shared MLP is the released-equivalent one, with the gin-bound MLP settings."""

  @nn.nowrap
  def make_mlp(self) -> ReleasedMLP:
    return released_mlp(super().make_mlp())
