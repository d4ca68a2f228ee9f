"""mip-NeRF with FreeNeRF's frequency-mask hooks: the MLP and the two-level model (flax.linen, gin)."""

from typing import Any, Callable

import flax.linen as nn
import gin
import jax
import jax.numpy as jnp
from jax import random

from internal import encoding
from internal import gaussians
from internal import sampling
from internal import volume_render

gin.config.external_configurable(nn.relu, name='relu', module='flax.nn')
gin.config.external_configurable(nn.softplus, name='softplus', module='flax.nn')
gin.config.external_configurable(nn.sigmoid, name='sigmoid', module='flax.nn')


@gin.configurable
class MLP(nn.Module):
  """The shared NeRF MLP; it runs on flattened [N, C] samples for speed."""
  net_depth: int = 8
  net_width: int = 256
  net_depth_viewdirs: int = 1
  net_width_viewdirs: int = 128
  net_activation: Callable[..., Any] = nn.relu
  min_deg_point: int = 0
  max_deg_point: int = 16
  deg_view: int = 4
  skip_layer: int = 4
  density_activation: Callable[..., Any] = nn.softplus
  density_bias: float = -1.
  density_noise: float = 0.
  density_noise_shared: bool = False  # True reproduces the released single draw per batch.
  rgb_activation: Callable[..., Any] = nn.sigmoid
  rgb_padding: float = 0.001
  use_viewdirs: bool = True

  def setup(self):
    dense = lambda width, i: nn.Dense(
        width, kernel_init=jax.nn.initializers.glorot_uniform(), name=f'Dense_{i}')
    self.trunk = [dense(self.net_width, i) for i in range(self.net_depth)]
    self.density_layer = dense(1, self.net_depth)
    self.bottleneck_layer = dense(self.net_width, self.net_depth + 1)
    self.view_layers = [dense(self.net_width_viewdirs, self.net_depth + 2 + i)
                        for i in range(self.net_depth_viewdirs)]
    self.rgb_layer = dense(3, self.net_depth + 2 + self.net_depth_viewdirs)

  def predict_density(self, key, means, covs, mask_point):
    """Density [...] and trunk features [N, W] from Gaussians means, covs [..., 3]."""
    x = encoding.integrated_pos_enc(
        means.reshape(-1, 3), covs.reshape(-1, 3), self.min_deg_point, self.max_deg_point)
    if mask_point is not None:
      x = x * mask_point
    inputs = x
    for i, layer in enumerate(self.trunk):
      x = self.net_activation(layer(x))
      if i % self.skip_layer == 0 and i > 0:
        x = jnp.concatenate([x, inputs], axis=-1)
    raw_density = self.density_layer(x)[:, 0]
    if key is not None and self.density_noise > 0:
      shape = () if self.density_noise_shared else raw_density.shape
      raw_density = raw_density + self.density_noise * random.normal(key, shape)
    density = self.density_activation(raw_density + self.density_bias)
    return density.reshape(means.shape[:-1]), x

  def __call__(self, key, means, covs, viewdirs, mask_point, mask_view):
    """rgb [B, S, 3] and density [B, S] for Gaussians [B, S, 3] seen along viewdirs [B, 3]."""
    density, x = self.predict_density(key, means, covs, mask_point)
    if self.use_viewdirs:
      x = self.bottleneck_layer(x)
      view = encoding.pos_enc(viewdirs, 0, self.deg_view, append_identity=True)
      if mask_view is not None:
        view = view * mask_view
      view = jnp.broadcast_to(view[:, None, :], means.shape[:-1] + view.shape[-1:])
      x = jnp.concatenate([x, view.reshape(-1, view.shape[-1])], axis=-1)
      for layer in self.view_layers:
        x = self.net_activation(layer(x))
    rgb = self.rgb_activation(self.rgb_layer(x))
    rgb = rgb * (1 + 2 * self.rgb_padding) - self.rgb_padding
    return rgb.reshape(means.shape), density

  def normals(self, means, covs, mask_point):
    """Unit normals [..., 3] = -grad(density)/|grad| at Gaussians [..., 3] (no noise)."""
    (grad,) = nn.grad(lambda mlp, m: mlp.predict_density(None, m, covs, mask_point)[0].sum(),
                   self, means)
    norm = jnp.sqrt(jnp.maximum(jnp.sum(grad**2, axis=-1, keepdims=True),
                                jnp.finfo(jnp.float32).eps))
    return -grad / norm


@gin.configurable
class MipNerfModel(nn.Module):
  """Two-level mip-NeRF sharing one MLP: coarse stratified samples, then resampled fine ones."""
  num_samples: int = 128
  num_levels: int = 2
  stop_level_grad: bool = True
  ray_shape: str = 'cone'
  disable_integration: bool = False
  white_background: bool = True

  def setup(self):
    self.mlp = MLP()

  def __call__(self, key, rays, mask_point=None, mask_view=None, resample_padding=0.01,
               compute_extras=False, compute_normals=False):
    """Renders rays [B, ...]; returns (renderings, ray_history), one dict per level."""
    keys = random.split(key, 2 * self.num_levels) if key is not None else [None] * (2 * self.num_levels)
    renderings, history = [], []
    for level in range(self.num_levels):
      sample_key, noise_key = keys[2 * level], keys[2 * level + 1]
      if level == 0:
        t_vals = sampling.stratified_t_vals(sample_key, rays.near, rays.far, self.num_samples)
      else:
        weights = history[-1]['weights']
        if self.stop_level_grad:
          weights = jax.lax.stop_gradient(weights)
        t_vals = sampling.resample_t_vals(sample_key, t_vals, weights, resample_padding)
      means, covs = gaussians.cast_rays(t_vals, rays.origins, rays.directions, rays.radii,
                                        self.ray_shape)
      if self.disable_integration:
        covs = jnp.zeros_like(covs)
      rgb, density = self.mlp(noise_key, means, covs, rays.viewdirs, mask_point, mask_view)
      rendering = volume_render.volumetric_rendering(
          rgb, density, t_vals, rays.directions, self.white_background, compute_extras)
      if compute_normals:
        normals = self.mlp.normals(means, covs, mask_point)
        rendering['normals'] = jnp.sum(rendering['weights'][..., None] * normals, axis=-2)
      renderings.append(rendering)
      history.append({'weights': rendering['weights'], 'rgb': rgb, 'density': density,
                      't_vals': t_vals})
    return renderings, history


def construct_model(key, example_rays, white_background: bool):
  """Builds MipNerfModel (gin-bound) and initializes its variables on example rays [B, ...]."""
  model = MipNerfModel(white_background=white_background)
  variables = model.init(key, None, example_rays)
  return model, variables


def num_params(params) -> int:
  """Total number of scalars in a parameter tree."""
  return sum(x.size for x in jax.tree.leaves(params))
