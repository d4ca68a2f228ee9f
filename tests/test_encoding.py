"""Tests of internal/models/encoding.py: lengths, the released index map, IPE expectations, stability."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.models import encoding
from internal.models import trig


def test_lengths():
  x = jnp.ones((2, 5, 3))
  assert encoding.pos_enc(x, 0, 16).shape == (2, 5, 99)
  assert encoding.pos_enc(x[:, 0], 0, 4).shape == (2, 27)
  assert encoding.pos_enc(x, 0, 4, append_identity=False).shape == (2, 5, 24)
  assert encoding.integrated_pos_enc(x, x, 0, 16).shape == (2, 5, 99)
  assert encoding.integrated_pos_enc(x, x, 0, 16, append_identity=False).shape == (2, 5, 96)
  assert all(a.shape == (99,) for a in encoding.feature_layout(16))
  assert all(a.shape == (27,) for a in encoding.feature_layout(4))
  assert all(a.shape == (24,) for a in encoding.feature_layout(4, append_identity=False))


def test_width_matches_a_hand_count_and_the_encodings():
  assert encoding.width(16) == 3 + 16 * 3 * 2 == 99  # Identity, then 16 degrees of sin and cos of x, y, z.
  assert encoding.width(4) == 3 + 4 * 3 * 2 == 27
  assert encoding.width(4, append_identity=False) == 24
  assert encoding.width(2, num_coords=2) == 10
  x = jnp.ones((2, 3))
  for degrees, identity in ((16, True), (4, True), (5, False), (0, True)):
    assert encoding.pos_enc(x, 0, degrees, identity).shape[-1] == encoding.width(degrees, append_identity=identity)
    assert encoding.feature_layout(degrees, append_identity=identity)[0].shape == (
        encoding.width(degrees, append_identity=identity),)


def _table(num_degrees):
  """The released feature order written out (identity, all sin, then all cos): index -> (kind, degree, coord)."""
  table = {c: (0, -1, c) for c in range(3)}
  cos_start = 3 + 3 * num_degrees  # 51 for 16 degrees, 15 for 4 degrees
  for k in range(num_degrees):
    for c in range(3):
      table[3 + 3 * k + c] = (1, k, c)
      table[cos_start + 3 * k + c] = (2, k, c)
  return table


@pytest.mark.parametrize('num_degrees,cos_start', [(16, 51), (4, 15)])
def test_feature_layout_matches_protocol_table(num_degrees, cos_start):
  kind, degree, coord = encoding.feature_layout(num_degrees)
  table = _table(num_degrees)
  assert 3 + 3 * num_degrees == cos_start and len(table) == len(kind)
  for i, expected in table.items():
    assert (kind[i], degree[i], coord[i]) == expected, i


@pytest.mark.parametrize('num_degrees', [16, 4])
def test_pos_enc_values_follow_layout(num_degrees):
  x = np.array([[0.3, -0.7, 0.05], [-0.01, 0.02, 0.9]], np.float32)
  enc = np.asarray(encoding.pos_enc(jnp.asarray(x), 0, num_degrees))
  for i, (kind, deg, c) in enumerate(zip(*encoding.feature_layout(num_degrees))):
    arg = 2.**deg * x[:, c].astype(np.float64)
    expected = {0: x[:, c], 1: np.sin(arg), 2: np.cos(arg)}[kind]
    np.testing.assert_allclose(enc[:, i], expected, atol=2e-5 * max(1., 2.**deg * 0.9), err_msg=str(i))


def test_pos_enc_min_deg_and_no_identity():
  x = jnp.array([[0.2, 0.4, -0.3]])
  full = encoding.pos_enc(x, 0, 4, append_identity=False)
  part = encoding.pos_enc(x, 2, 4, append_identity=False)
  np.testing.assert_allclose(part, jnp.concatenate([full[:, 6:12], full[:, 18:24]], -1), rtol=1e-6)


def test_ipe_zero_variance_equals_pos_enc_and_identity_is_raw_mean():
  mean = jax.random.uniform(jax.random.PRNGKey(0), (7, 3), minval=-2., maxval=2.)
  ipe = encoding.integrated_pos_enc(mean, jnp.zeros_like(mean), 0, 16)
  np.testing.assert_array_equal(ipe[:, :3], mean)
  small = encoding.integrated_pos_enc(mean, jnp.zeros_like(mean), 0, 7)  # |2^k x| < 100 pi: no mod
  np.testing.assert_allclose(small, encoding.pos_enc(mean, 0, 7), atol=1e-5)


def test_ipe_matches_monte_carlo_expectation():
  """E[sin(2^k x)] and E[cos(2^k x)] over x ~ N(mean, var), by sampling (float64) and closed form."""
  rng = np.random.default_rng(0)
  mean = np.array([0.4, -1.3, 2.2])
  var = np.array([0.02, 0.002, 0.3])
  num = 1_000_000
  samples = mean + np.sqrt(var) * rng.standard_normal((num, 3))
  ipe = np.asarray(encoding.integrated_pos_enc(jnp.asarray(mean, jnp.float32),
                                               jnp.asarray(var, jnp.float32), 0, 5))
  kind, degree, coord = encoding.feature_layout(5)
  for i in range(3, len(kind)):
    arg = 2.**degree[i] * samples[:, coord[i]]
    vals = np.sin(arg) if kind[i] == 1 else np.cos(arg)
    tol = 5. * vals.std() / np.sqrt(num) + 1e-5
    assert abs(ipe[i] - vals.mean()) < tol, (i, ipe[i], vals.mean())
    scaled_mean = 2.**degree[i] * mean[coord[i]]
    closed = np.exp(-0.5 * 4.**degree[i] * var[coord[i]]) * (
        np.sin(scaled_mean) if kind[i] == 1 else np.cos(scaled_mean))
    assert abs(ipe[i] - closed) < 2e-6, (i, ipe[i], closed)


def _released_pos_enc(x, min_deg, max_deg):
  """The released pos_enc with XLA's jnp.sin: [x | sin(x 2^d) | sin(x 2^d + pi/2)], degree-major blocks."""
  scales = jnp.array([2.**i for i in range(min_deg, max_deg)])
  xb = jnp.reshape(x[..., None, :] * scales[:, None], x.shape[:-1] + (-1,))
  return jnp.concatenate([x, jnp.sin(jnp.concatenate([xb, xb + 0.5 * jnp.pi], axis=-1))], axis=-1)


EXTREME = np.array([[0.3, -2e3, 8191.], [1e4, -3e6, 7.7e11], [3.4e38, -1e30, 1e-30], [2e5, 65537., -1.5e8]],
                   np.float32)


def test_pos_enc_of_extreme_inputs_equals_the_released_encoding_with_jnp_sin():
  ours = np.asarray(jax.jit(lambda x: encoding.pos_enc(x, 0, 16))(EXTREME))
  released = np.asarray(jax.jit(lambda x: _released_pos_enc(x, 0, 16))(EXTREME))
  np.testing.assert_allclose(ours, released, rtol=0, atol=1.5e-7)  # Both within float32 rounding of exact.


def test_interleaved_pos_enc_of_extreme_inputs_equals_jnp_sin_and_cos():
  ours = np.asarray(jax.jit(lambda x: encoding.interleaved_pos_enc(x, 10))(EXTREME))
  scaled = jnp.asarray(EXTREME)[:, None, :] * 2.**jnp.arange(10.)[:, None]  # [N, degree, coord], some inf.
  bands = np.stack([jnp.sin(scaled), jnp.cos(scaled)], axis=2).reshape(len(EXTREME), -1)
  np.testing.assert_allclose(ours, np.concatenate([EXTREME, bands], -1), rtol=0, atol=1.5e-7)


def _below_the_guard(top_degree: int, n: int = 30_000) -> np.ndarray:
  """Coordinates [n, 3] whose arguments at 2^top_degree fill [EXACT_SIN_LIMIT / 2, EXACT_SIN_LIMIT - 2) (+ pi/2
  stays below the limit), so that every argument takes trig's own reduction (the whole array is below its guard)."""
  limit = trig.EXACT_SIN_LIMIT
  y = np.random.default_rng(1).uniform(limit / 2, limit - 2., (n, 3)) * np.random.default_rng(2).choice([-1, 1], (n, 3))
  return (y / 2.**top_degree).astype(np.float32)


def _exact_sin(arguments: np.ndarray) -> np.ndarray:
  """sin of float32 arguments in float64, asserting that they are below trig's guard."""
  assert np.max(np.abs(arguments)) < trig.EXACT_SIN_LIMIT
  return np.sin(arguments.astype(np.float64))


def test_pos_enc_of_arrays_below_the_guard_is_within_float32_rounding_of_exact():
  x = _below_the_guard(15)
  ours = np.asarray(jax.jit(lambda x: encoding.pos_enc(x, 0, 16))(x))
  scaled = (x[:, None, :] * 2.**np.arange(16)[:, None]).astype(np.float32).reshape(len(x), -1)  # Exact products.
  shifted = scaled + np.float32(0.5 * np.pi)  # float32 additions, as the encoding's.
  np.testing.assert_allclose(ours, np.concatenate([x, _exact_sin(scaled), _exact_sin(shifted)], -1), rtol=0,
                             atol=1.2e-7)


def test_interleaved_pos_enc_of_arrays_below_the_guard_is_within_float32_rounding_of_exact():
  x = _below_the_guard(9)
  ours = np.asarray(jax.jit(lambda x: encoding.interleaved_pos_enc(x, 10))(x))
  scaled = (x[:, None, :] * 2.**np.arange(10)[:, None]).astype(np.float32)  # [N, degree, coord]
  bands = np.stack([_exact_sin(scaled), np.cos(scaled.astype(np.float64))], axis=2).reshape(len(x), -1)
  np.testing.assert_allclose(ours, np.concatenate([x, bands], -1), rtol=0, atol=1.2e-7)


def test_safe_sin_large_arguments():
  x = jnp.array([1., 300., 400., -500., 1e4, 3.3e8])
  y = encoding.safe_sin(x)
  np.testing.assert_allclose(y[:5], np.sin(np.asarray(x[:5], np.float64)), atol=5e-4)
  assert np.all(np.isfinite(y)) and np.all(np.abs(y) <= 1.)


@pytest.mark.parametrize('cov_scale', [0., 1e-6, 1.])
def test_ipe_large_coordinates_finite_with_gradients(cov_scale):
  mean = jnp.array([[1e4, -1e4, 5e3], [0.5, 0.1, -0.2]])
  cov = jnp.full_like(mean, cov_scale)

  def loss(mean, cov):
    return jnp.sum(encoding.integrated_pos_enc(mean, cov, 0, 16))

  enc = encoding.integrated_pos_enc(mean, cov, 0, 16)
  assert np.all(np.isfinite(enc)) and np.all(np.abs(enc[:, 3:]) <= 1.)
  grads = jax.grad(loss, argnums=(0, 1))(mean, cov)
  assert all(np.all(np.isfinite(g)) for g in grads)


def test_zero_length_view_direction_finite():
  d = jnp.zeros((2, 3))
  enc = encoding.pos_enc(d, 0, 4)
  np.testing.assert_allclose(enc, np.concatenate([np.zeros((2, 15)), np.ones((2, 12))], -1), atol=1e-6)
  grad = jax.grad(lambda d: jnp.sum(encoding.pos_enc(d, 0, 4)))(d)
  assert np.all(np.isfinite(grad))
