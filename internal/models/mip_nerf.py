"""mip-NeRF with FreeNeRF's frequency-mask hooks: the MLP and the two-level model (flax.linen, gin)."""

from typing import Any, Callable, Optional

import flax.linen as nn
import gin
import jax
import jax.numpy as jnp
from jax import random

from internal.models import activations
from internal.models import dense
from internal.models import encoding
from internal.models import fused_dense
from internal.models import gaussians
from internal.models import precision as precision_lib
from internal.models import sampling
from internal.models import volume_render

gin.config.external_configurable(nn.relu, name='relu', module='flax.nn')
gin.config.external_configurable(nn.softplus, name='softplus', module='flax.nn')
gin.config.external_configurable(nn.sigmoid, name='sigmoid', module='flax.nn')
gin.config.external_configurable(activations.relu_from_output, name='relu_from_output')  # A step variant.
DENSE_KERNELS = ('xla', 'pallas', 'folded_bias')
@gin.configurable(denylist=['precision'])
class MLP(nn.Module):
  """The shared NeRF MLP, as pure functions of its Dense_i parameters (released names and shapes)."""
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
  density_noise_shared: bool = True  # One draw per batch, as released; False draws one per sample.
  rgb_activation: Callable[..., Any] = nn.sigmoid
  rgb_padding: float = 0.001
  use_viewdirs: bool = True
  # The raw coordinates (the Gaussians' means) concatenated before the IPE: FreeNeRF's one change to mip-NeRF
  # (99 features). False drops them (96, as mip-NeRF and RegNeRF released), the xyz ablation.
  point_identity: bool = True
  # How the trunk's hidden layers run: 'xla' (XLA's matmuls), 'pallas' (internal/models/fused_dense.py: the
  # bias, ReLU and its gradient fused into the products; a GPU step variant, interpreted on a CPU) or
  # 'folded_bias' (XLA's matmuls with each bias folded into its kernel as a row, met by a ones column the
  # activations carry: no bias pass or bias-gradient reduction left; a step variant).
  dense_kernel: str = 'xla'
  precision: str = 'float32'  # One of precision.PRECISIONS, set from Config.precision (not a gin binding).

  def setup(self):
    self.layers = {name: self.param(name, dense.glorot_layer(i, o)) for name, i, o in self.layer_shapes()}
    self.dtype, self.matmul_precision = precision_lib.settings(self.precision)
    self.tiles, self.passes = self.check_dense_kernel()

  @nn.nowrap
  def check_dense_kernel(self):
    """(Tiles, Passes) of the fused layer as gin binds them; ValueError naming MLP.dense_kernel or
    .net_activation if it cannot run (a bad FusedDenseTiles or FusedDensePasses setting is named by them); a
    one-line warning where the fused kernels would run interpreted."""
    if self.dense_kernel not in DENSE_KERNELS:
      raise ValueError(f'MLP.dense_kernel = {self.dense_kernel!r}; expected one of {list(DENSE_KERNELS)}')
    if self.dense_kernel == 'pallas' and jax.device_count() > 1:
      raise ValueError(f"MLP.dense_kernel = 'pallas' runs on one device; this run has {jax.device_count()}, over "
                       "which XLA cannot split a custom kernel (use one, e.g. CUDA_VISIBLE_DEVICES=0, or 'xla')")
    relu = {self.net_activation, getattr(self.net_activation, '__wrapped__', None)}  # gin's @name wraps it.
    if self.dense_kernel != 'xla' and not relu & {nn.relu, activations.relu_from_output}:
      why = 'fuses ReLU into the layer' if self.dense_kernel == 'pallas' else 'passes its ones column through ReLU'
      raise ValueError(f"MLP.dense_kernel = {self.dense_kernel!r} {why}; MLP.net_activation is "
                       f'{getattr(self.net_activation, "__name__", self.net_activation)}, expected relu')
    if self.dense_kernel == 'pallas':
      fused_dense.warn_if_interpreted()
    return fused_dense.FusedDenseTiles(), fused_dense.FusedDensePasses()

  def _dense(self, name: str, *parts, ones: bool = False):
    """Dense layer `name` of parts [..., d_i] at this MLP's matmul precision; ones: parts[0] carries with_ones'
    columns (MLP.dense_kernel = 'folded_bias'), which meet the bias folded into the kernel."""
    if not ones:
      return dense.dense(self.layers[name], *parts, precision=self.matmul_precision)
    kernel = dense.folded_kernel(self.layers[name], parts[0].shape[-1] - dense.FOLD_PAD, ones_out=False)
    return dense.sum_of(dense.matmuls(kernel, *parts, precision=self.matmul_precision))

  def _hidden(self, i: int, *parts):
    """net_activation(dense layer i) [N, width] of parts [N, d_i], in the kernel MLP.dense_kernel names (with
    'folded_bias', parts[0] and the output [N, width + FOLD_PAD] carry with_ones' columns)."""
    layer = self.layers[f'Dense_{i}']
    if self.dense_kernel == 'xla':
      return self.net_activation(self._dense(f'Dense_{i}', *parts))
    if self.dense_kernel == 'folded_bias':
      kernel = dense.folded_kernel(layer, parts[0].shape[-1] - dense.FOLD_PAD, ones_out=True)
      return self.net_activation(dense.sum_of(dense.matmuls(kernel, *parts, precision=self.matmul_precision)))
    # Each hidden layer's output feeds the next one only, which can then mask its gradient (mask_at_store).
    masks = self.passes.mask_at_store
    return fused_dense.dense_relu(parts, layer['kernel'], layer['bias'], self.matmul_precision, self.tiles,
                                  two_inputs=self.passes.two_inputs, mask_input_gradient=masks and i > 0,
                                  gradient_masked=masks and i < self.net_depth - 1)

  def _skip_after(self, i: int) -> bool:
    return i % self.skip_layer == 0 and i > 0

  def encoding_degrees(self):
    """(point, view) encoding degrees: they fix the encoding widths and the frequency masks' lengths."""
    return self.max_deg_point - self.min_deg_point, self.deg_view

  def layer_shapes(self):
    """(name, inputs, outputs) of every dense layer, named Dense_0.. in the released order."""
    deg_point, deg_view = self.encoding_degrees()
    point_dim = encoding.width(deg_point, append_identity=self.point_identity)
    shapes, width = [], point_dim
    for i in range(self.net_depth):
      shapes.append((f'Dense_{i}', width, self.net_width))
      width = self.net_width + (point_dim if self._skip_after(i) else 0)
    heads = [(width, 1)]
    if self.use_viewdirs:
      heads.append((width, self.net_width))
      width = self.net_width + encoding.width(deg_view)
      for _ in range(self.net_depth_viewdirs):
        heads.append((width, self.net_width_viewdirs))
        width = self.net_width_viewdirs
    heads.append((width, 3))
    return shapes + [(f'Dense_{self.net_depth + k}', i, o) for k, (i, o) in enumerate(heads)]

  def _density(self, means, covs, mask_point, noise):
    """Density [N] and trunk features (parts [N, ...]) of Gaussians [N, 3]; noise [N] or a scalar."""
    enc = encoding.integrated_pos_enc(means, covs, self.min_deg_point, self.max_deg_point, self.point_identity)
    if mask_point is not None:
      enc = enc * mask_point
    enc = enc.astype(self.dtype)  # The IPE (sines of large arguments) and its mask stay float32.
    ones = self.dense_kernel == 'folded_bias'
    x = (dense.with_ones(enc) if ones else enc,)
    for i in range(self.net_depth):
      x = (self._hidden(i, *x),)
      if self._skip_after(i):
        x += (enc,)  # The skip connection re-uses the masked encoding.
    raw_density = self._dense(f'Dense_{self.net_depth}', *x, ones=ones)[:, 0].astype(jnp.float32) + noise
    return self.density_activation(raw_density + self.density_bias), x

  def _colour(self, features, view, num_samples: int):
    """rgb [B*S, 3] from trunk features (parts [B*S, ...]) and encoded view directions [B, V]."""
    names = iter(name for name, _, _ in self.layer_shapes()[self.net_depth + 1:])  # The heads after density.
    ones = self.dense_kernel == 'folded_bias'  # The trunk's features carry with_ones' columns.
    if self.use_viewdirs:
      bottleneck = self._dense(next(names), *features, ones=ones)
      layer = self.layers[next(names)]
      # [bottleneck, view] @ kernel, with the view term computed once per ray, not per sample.
      width = bottleneck.shape[-1]
      per_sample = dense.matmul(bottleneck, layer['kernel'][:width], self.matmul_precision)
      per_ray = dense.add_bias(dense.matmul(view, layer['kernel'][width:], self.matmul_precision), layer['bias'])
      x = per_sample.reshape((-1, num_samples) + per_sample.shape[1:]) + per_ray[:, None]
      features = (self.net_activation(x.reshape(per_sample.shape)),)
      for _ in range(self.net_depth_viewdirs - 1):
        features = (self.net_activation(self._dense(next(names), *features)),)
      ones = False
    rgb = self.rgb_activation(self._dense(next(names), *features, ones=ones).astype(jnp.float32))
    return rgb * (1 + 2 * self.rgb_padding) - self.rgb_padding

  def _noise(self, key, shape):
    """Training density noise [shape] (or one shared scalar); 0 at eval or when disabled."""
    if key is None or self.density_noise <= 0:
      return jnp.zeros(shape)
    draw = random.normal(key, () if self.density_noise_shared else shape)
    return jnp.broadcast_to(self.density_noise * draw, shape)

  def predict_density(self, key, means, covs, mask_point):
    """Density [...] of Gaussians means, covs [..., 3]."""
    flat = means.reshape(-1, 3)
    density, _ = self._density(flat, covs.reshape(-1, 3), mask_point, self._noise(key, flat.shape[:1]))
    return density.reshape(means.shape[:-1])

  def __call__(self, key, means, covs, viewdirs, mask_point, mask_view):
    """rgb [B, S, 3] and density [B, S] for Gaussians [B, S, 3] seen along viewdirs [B, 3]."""
    view = encoding.pos_enc(viewdirs, 0, self.deg_view, append_identity=True)
    if mask_view is not None:
      view = view * mask_view
    view = view.astype(self.dtype)
    flat = means.reshape(-1, 3)
    density, features = self._density(flat, covs.reshape(-1, 3), mask_point,
                                      self._noise(key, flat.shape[:1]))
    rgb = self._colour(features, view, means.shape[-2])
    return rgb.reshape(means.shape), density.reshape(means.shape[:-1])

  def normals(self, means, covs, mask_point):
    """Unit normals [..., 3] = -grad(density)/|grad| at Gaussians [..., 3] (no noise)."""
    grad = jax.grad(lambda m: self.predict_density(None, m, covs, mask_point).sum())(means)
    norm = jnp.sqrt(jnp.maximum(jnp.sum(grad**2, axis=-1, keepdims=True),
                                jnp.finfo(jnp.float32).eps))
    return -grad / norm


@gin.configurable(denylist=['precision', 'white_background', 'mlp'])
class MipNerfModel(nn.Module):
  """Two-level mip-NeRF sharing one MLP: coarse stratified samples, then resampled fine ones."""
  num_samples: int = 128
  num_levels: int = 2
  stop_level_grad: bool = True
  ray_shape: str = 'cone'
  disable_integration: bool = False
  white_background: bool = True  # Set from Config.white_background (not a gin binding), as the data's background.
  pdf_padding: str = 'released'  # 'released' | 'even': see docs/numerics.md.
  precision: str = 'float32'  # Set from Config.precision, passed on to the MLP.
  mlp: Optional[MLP] = None  # The shared MLP; None builds make_mlp() (gin-bound, at `precision`).

  interleaved_encoding = False  # A class constant, not a field: the released block order [id | sin | cos].

  def __post_init__(self):
    if self.mlp is None:  # Built now, not in setup, so that its encoding degrees are known before init.
      object.__setattr__(self, 'mlp', self.make_mlp())
    super().__post_init__()

  @nn.nowrap  # Not a module method: the MLP it builds has no parent until the model adopts it.
  def make_mlp(self) -> MLP:
    """The gin-bound MLP at this model's precision."""
    return MLP(precision=self.precision)

  @nn.nowrap
  def encoding_degrees(self):
    """(point, view) encoding degrees of the shared MLP."""
    return self.mlp.encoding_degrees()

  @nn.nowrap
  def point_identity(self) -> bool:
    """Whether the shared MLP's point encoding starts with the raw coordinates (MLP.point_identity)."""
    return self.mlp.point_identity

  @nn.nowrap
  def fine_samples_per_ray(self) -> int:
    """Samples per ray of the last level (the occlusion loss's sample axis)."""
    return self.num_samples

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
        t_vals = sampling.resample_t_vals(sample_key, t_vals, weights, resample_padding,
                                           self.pdf_padding)
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


  def density_at(self, points, variance, mask_point):
    """Density [N] at points [N, 3], each a Gaussian of isotropic variance (a grid cell's footprint), no noise."""
    return self.mlp.predict_density(None, points, jnp.full_like(points, variance), mask_point)

  def colour_at(self, points, viewdirs, variance, mask_point, mask_view):
    """rgb [N, 3] at points [N, 3] (Gaussians as in density_at) seen along viewdirs [N, 3]."""
    rgb, _ = self.mlp(None, points[:, None], jnp.full_like(points, variance)[:, None], viewdirs, mask_point,
                      mask_view)
    return rgb[:, 0]


def construct_model(key, example_rays, white_background: bool, precision: str = 'float32'):
  """Builds MipNerfModel (gin-bound) and initializes its variables on example rays [B, ...]."""
  model = MipNerfModel(white_background=white_background, precision=precision)
  variables = jax.jit(model.init)(key, None, example_rays)  # One compile, not one per operation.
  return model, variables
