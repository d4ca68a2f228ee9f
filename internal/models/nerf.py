"""Plain NeRF, as the released Blender (PyTorch) code builds it: separate coarse and fine MLPs on points.

NerfModel has MipNerfModel's call signature and outputs (renderings and ray history per level, same keys), so
the train step, losses, checkpoints and evaluation use either one unchanged; `Config.model` picks it.
"""

from typing import Optional

import flax.linen as nn
import gin
import jax
import jax.numpy as jnp
from jax import random

from internal.models import encoding
from internal.models import dense
from internal.models import precision as precision_lib
from internal.models import sampling
from internal.models import volume_render


WEIGHT_INITS = ('torch_linear', 'xavier')  # NerfMLP.weight_init: torch_linear_init or xavier_init.


def torch_linear_init(in_dim: int, out_dim: int, gain: float):
  """PyTorch nn.Linear's default: kernel [in, out] and bias [out] uniform in +-1/sqrt(in) (gain unused)."""
  del gain
  bound = 1. / in_dim**0.5

  def init(key):
    kernel_key, bias_key = random.split(key)
    return {'kernel': random.uniform(kernel_key, (in_dim, out_dim), minval=-bound, maxval=bound),
            'bias': random.uniform(bias_key, (out_dim,), minval=-bound, maxval=bound)}
  return init


def xavier_init(in_dim: int, out_dim: int, gain: float):
  """The released Blender code's layers: kernel [in, out] Xavier-uniform, +-gain*sqrt(6/(in+out)); bias [out] 0."""
  bound = gain * (6. / (in_dim + out_dim))**0.5

  def init(key):
    return {'kernel': random.uniform(key, (in_dim, out_dim), minval=-bound, maxval=bound),
            'bias': jnp.zeros((out_dim,), jnp.float32)}
  return init


def layer_init(weight_init: str, in_dim: int, out_dim: int, relu: bool):
  """The initializer of one dense layer: NerfMLP.weight_init's rule, gain sqrt(2) before a ReLU, else 1."""
  inits = {'torch_linear': torch_linear_init, 'xavier': xavier_init}
  if weight_init not in inits:
    raise ValueError(f'NerfMLP.weight_init = {weight_init!r}; expected one of {list(WEIGHT_INITS)}')
  return inits[weight_init](in_dim, out_dim, 2.**0.5 if relu else 1.)


@gin.configurable(denylist=['precision'])
class NerfMLP(nn.Module):
  """NeRF's MLP on interleaved positional encodings: a ReLU trunk with one skip, density, a view branch."""
  net_depth: int = 8
  net_width: int = 256
  net_width_viewdirs: int = 128
  skip_layer: int = 4  # The encoded input is concatenated (first) to the output of trunk layer skip_layer (0-based).
  deg_point: int = 10
  deg_view: int = 4
  use_viewdirs: bool = True
  density_noise: float = 0.  # Std of N(0, 1) noise per sample on the raw density, in training (0 = none).
  point_identity: bool = True  # The raw points first in their encoding, as released; False drops them (xyz ablation).
  # 'torch_linear': PyTorch nn.Linear's default; 'xavier': Xavier-uniform kernels (gain sqrt(2) before a ReLU, 1
  # for the density, feature and rgb heads) and zero biases, as the released Blender code's layers.
  weight_init: str = 'torch_linear'
  precision: str = 'float32'  # One of precision.PRECISIONS, set from Config.precision (not a gin binding).

  def setup(self):
    relu = self.relu_layers()
    self.layers = {name: self.param(name, layer_init(self.weight_init, i, o, name in relu))
                   for name, i, o in self.layer_shapes()}
    self.dtype, self.matmul_precision = precision_lib.settings(self.precision)

  def encoding_degrees(self):
    """(point, view) encoding degrees: they fix the encoding widths and the frequency masks' lengths."""
    return self.deg_point, self.deg_view

  def _skip_after(self, i: int) -> bool:
    return i == self.skip_layer and i < self.net_depth - 1

  def layer_shapes(self):
    """(name, inputs, outputs) of every dense layer: trunk Dense_0.., then density, feature, view, rgb heads."""
    point_dim = encoding.width(self.deg_point, append_identity=self.point_identity)
    view_dim = encoding.width(self.deg_view)
    shapes, width = [], point_dim
    for i in range(self.net_depth):
      shapes.append((f'Dense_{i}', width, self.net_width))
      width = self.net_width + (point_dim if self._skip_after(i) else 0)
    if self.use_viewdirs:
      heads = [(width, 1), (width, width), (width + view_dim, self.net_width_viewdirs),
               (self.net_width_viewdirs, 3)]
    else:
      heads = [(width, 1), (width, 3)]
    return shapes + [(f'Dense_{self.net_depth + k}', i, o) for k, (i, o) in enumerate(heads)]

  def relu_layers(self):
    """Names of the layers a ReLU follows: the trunk and, with view directions, the view layer."""
    trunk = {f'Dense_{i}' for i in range(self.net_depth)}
    return trunk | ({f'Dense_{self.net_depth + 2}'} if self.use_viewdirs else set())

  def _dense(self, index: int, *parts):
    """Dense layer Dense_index of parts [..., d_i] at this MLP's matmul precision."""
    return dense.dense(self.layers[f'Dense_{index}'], *parts, precision=self.matmul_precision)

  def _trunk(self, points, mask_point):
    """Trunk features [N, W] of points [N, 3] (mask_point [63] or None multiplies their encoding)."""
    enc = encoding.interleaved_pos_enc(points, self.deg_point, self.point_identity)
    if mask_point is not None:
      enc = enc * mask_point
    enc = enc.astype(self.dtype)
    x = (enc,)
    for i in range(self.net_depth):
      h = nn.relu(self._dense(i, *x))
      x = (enc, h) if self._skip_after(i) else (h,)  # The skip re-uses the masked encoding.
    return x

  def _raw_density(self, points, mask_point):
    """(raw density [N] before noise and ReLU, trunk features) of points [N, 3]."""
    features = self._trunk(points, mask_point)
    return self._dense(self.net_depth, *features)[:, 0].astype(jnp.float32), features

  def predict_density(self, points, mask_point):
    """Density [...] = ReLU(raw) at points [..., 3], without noise."""
    raw, _ = self._raw_density(points.reshape(-1, 3), mask_point)
    return nn.relu(raw).reshape(points.shape[:-1])

  def _colour(self, features, view, num_samples: int):
    """rgb [B*S, 3] from trunk features (parts [B*S, ...]) and encoded view directions [B, V] or None."""
    d = self.net_depth
    if not self.use_viewdirs:
      return nn.sigmoid(self._dense(d + 1, *features).astype(jnp.float32))
    feature = self._dense(d + 1, *features)  # No activation, as in the released code.
    layer = self.layers[f'Dense_{d + 2}']
    width = feature.shape[-1]
    # [feature, view] @ kernel with the view term computed once per ray, not per sample.
    per_sample = dense.matmul(feature, layer['kernel'][:width], self.matmul_precision)
    per_ray = dense.add_bias(dense.matmul(view, layer['kernel'][width:], self.matmul_precision), layer['bias'])
    x = per_sample.reshape((-1, num_samples) + per_sample.shape[1:]) + per_ray[:, None]
    h = nn.relu(x.reshape(per_sample.shape))
    return nn.sigmoid(self._dense(d + 3, h).astype(jnp.float32))

  def __call__(self, key, points, viewdirs, mask_point, mask_view):
    """rgb [B, S, 3] and density [B, S] at points [B, S, 3] seen along viewdirs [B, 3]."""
    view = encoding.interleaved_pos_enc(viewdirs, self.deg_view)
    if mask_view is not None:
      view = view * mask_view
    flat = points.reshape(-1, 3)
    raw, features = self._raw_density(flat, mask_point)
    if key is not None and self.density_noise > 0:
      raw = raw + self.density_noise * random.normal(key, raw.shape)
    rgb = self._colour(features, view.astype(self.dtype), points.shape[-2])
    return rgb.reshape(points.shape), nn.relu(raw).reshape(points.shape[:-1])

  def normals(self, points, mask_point):
    """Unit normals [..., 3] = -grad(density)/|grad| at points [..., 3] (no noise)."""
    grad = jax.grad(lambda p: self.predict_density(p, mask_point).sum())(points)
    norm = jnp.sqrt(jnp.maximum(jnp.sum(grad**2, axis=-1, keepdims=True), jnp.finfo(jnp.float32).eps))
    return -grad / norm


@gin.configurable(denylist=['precision', 'white_background', 'coarse_mlp', 'fine_mlp'])
class NerfModel(nn.Module):
  """Two-level NeRF: a coarse MLP on stratified points, a fine MLP on the sorted union with importance samples."""
  num_coarse_samples: int = 64
  num_fine_samples: int = 128  # Importance samples; the fine pass sees num_coarse + num_fine points per ray.
  white_background: bool = True  # Set from Config.white_background (not a gin binding).
  precision: str = 'float32'  # Set from Config.precision, passed on to both MLPs.
  coarse_mlp: Optional[NerfMLP] = None  # None builds the gin-bound NerfMLP.
  fine_mlp: Optional[NerfMLP] = None

  interleaved_encoding = True  # A class constant, not a field: NeRF interleaves sin and cos per degree.

  def __post_init__(self):
    for name in ('coarse_mlp', 'fine_mlp'):
      if getattr(self, name) is None:  # Built now, as in MipNerfModel, so the encoding is known before init.
        object.__setattr__(self, name, NerfMLP(precision=self.precision))
    super().__post_init__()

  @nn.nowrap
  def encoding_degrees(self):
    """(point, view) encoding degrees of both MLPs."""
    return self.coarse_mlp.encoding_degrees()

  @nn.nowrap
  def point_identity(self) -> bool:
    """Whether both MLPs' point encodings start with the raw points (NerfMLP.point_identity)."""
    return self.coarse_mlp.point_identity

  @nn.nowrap
  def fine_samples_per_ray(self) -> int:
    """Samples per ray of the fine pass (the occlusion loss's sample axis)."""
    return self.num_coarse_samples + self.num_fine_samples

  def _render(self, mlp, key, t_points, rays, masks, compute_extras, compute_normals):
    """(rendering, history) of one pass of mlp at sample distances t_points [B, S]."""
    points = rays.origins[..., None, :] + rays.directions[..., None, :] * t_points[..., None]
    rgb, density = mlp(key, points, rays.viewdirs, *masks)
    rendering = volume_render.point_rendering(rgb, density, t_points, rays.directions, self.white_background,
                                              compute_extras)
    if compute_normals:
      normals = mlp.normals(points, masks[0])
      rendering['normals'] = jnp.sum(rendering['weights'][..., None] * normals, axis=-2)
    # t_vals as interval edges [B, S+1]: the points, closed by far (the quadrature's last interval is open).
    t_vals = jnp.concatenate([t_points, jnp.broadcast_to(rays.far, t_points.shape[:-1] + (1,))], axis=-1)
    return rendering, {'weights': rendering['weights'], 'rgb': rgb, 'density': density, 't_vals': t_vals}

  def __call__(self, key, rays, mask_point=None, mask_view=None, resample_padding=0.01,
               compute_extras=False, compute_normals=False):
    """Renders rays [B, ...]; returns (renderings, ray_history), [coarse, fine]. resample_padding is unused."""
    del resample_padding  # NeRF pads its pdf with sampling.NERF_WEIGHT_PADDING instead.
    keys = random.split(key, 4) if key is not None else [None] * 4
    masks = (mask_point, mask_view)
    coarse_t = sampling.stratified_t_vals(keys[0], rays.near, rays.far, self.num_coarse_samples - 1)
    coarse, coarse_history = self._render(self.coarse_mlp, keys[1], coarse_t, rays, masks, compute_extras,
                                          compute_normals)
    fine_t = sampling.importance_samples(keys[2], coarse_t, coarse['weights'], self.num_fine_samples)
    fine_t = jnp.sort(jnp.concatenate([coarse_t, fine_t], axis=-1), axis=-1)
    fine, fine_history = self._render(self.fine_mlp, keys[3], fine_t, rays, masks, compute_extras,
                                      compute_normals)
    return [coarse, fine], [coarse_history, fine_history]


  def density_at(self, points, variance, mask_point):
    """Density [N] of the fine MLP (the one rendered last) at points [N, 3]; variance is unused (points)."""
    del variance  # NeRF encodes points, without a footprint.
    return self.fine_mlp.predict_density(points, mask_point)

  def colour_at(self, points, viewdirs, variance, mask_point, mask_view):
    """rgb [N, 3] of the fine MLP at points [N, 3] seen along viewdirs [N, 3]."""
    del variance
    rgb, _ = self.fine_mlp(None, points[:, None], viewdirs, mask_point, mask_view)
    return rgb[:, 0]


def construct_model(key, example_rays, white_background: bool, precision: str = 'float32'):
  """Builds NerfModel (gin-bound) and initializes its variables on example rays [B, ...]."""
  model = NerfModel(white_background=white_background, precision=precision)
  variables = jax.jit(model.init)(key, None, example_rays)
  return model, variables
