"""Gradient clipping (by value, then by global norm) and Adam's first step against hand computations."""

import jax.numpy as jnp
import numpy as np
import pytest

from internal.training import optim


def _grads():
  """A two-leaf tree whose global norm is 13 (3-4-12 triangle)."""
  return {'a': jnp.array([3., -4.]), 'b': jnp.array([[12.]])}


def test_global_norm_and_all_finite():
  assert float(optim.global_norm(_grads())) == pytest.approx(13.)
  assert bool(optim.all_finite(_grads()))
  assert not bool(optim.all_finite({'a': jnp.array([1., jnp.inf]), 'b': jnp.zeros(2)}))


def test_value_clip_then_global_norm_clip():
  grads, stats = optim.clip_gradients(_grads(), max_val=5., max_norm=1.)
  # Value clip: b 12 -> 5, norm sqrt(9 + 16 + 25) = sqrt(50); then everything scaled by 1 / sqrt(50).
  np.testing.assert_allclose(grads['a'], [3. / 50**.5, -4. / 50**.5], rtol=1e-6)
  np.testing.assert_allclose(grads['b'], [[5. / 50**.5]], rtol=1e-6)
  assert float(stats['grad_norm_raw']) == pytest.approx(13.)
  assert float(stats['grad_abs_max']) == 5.
  assert float(stats['grad_norm']) == pytest.approx(50**.5)
  assert float(stats['grad_norm_clipped']) == pytest.approx(1., rel=1e-6)


def test_global_norm_clip_alone_and_no_clip():
  grads, _ = optim.clip_gradients(_grads(), max_val=0., max_norm=2.6)  # Scale 2.6 / 13 = 0.2.
  np.testing.assert_allclose(grads['a'], [0.6, -0.8], rtol=1e-6)
  np.testing.assert_allclose(grads['b'], [[2.4]], rtol=1e-6)
  grads, stats = optim.clip_gradients(_grads(), max_val=0., max_norm=20.)  # Below the norm: unchanged.
  np.testing.assert_array_equal(grads['b'], [[12.]])
  grads, _ = optim.clip_gradients(_grads(), max_val=3.5, max_norm=0.)  # Value clip alone.
  np.testing.assert_array_equal(grads['a'], [3., -3.5])
  np.testing.assert_array_equal(grads['b'], [[3.5]])


def test_adam_first_step_is_g_over_abs_g_plus_eps():
  transform = optim.adam(eps=0.5)
  grads = {'w': jnp.array([0.5, -1.5])}
  updates, _ = transform.update(grads, transform.init(grads))
  # Bias-corrected moments after one step are g and g^2: update = g / (|g| + eps).
  np.testing.assert_allclose(updates['w'], [0.5 / 1., -1.5 / 2.], rtol=1e-5)  # float32 bias correction.
