"""Tests of internal/models/trig.py against float64 numpy and XLA's own remainder, at every octant and binade."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.models import trig

RNG = np.random.default_rng(0)


def _samples(limit: float) -> np.ndarray:
  """float32 samples of [-limit, limit]: uniform, near every multiple of pi/4, and exact zeros."""
  uniform = RNG.uniform(-limit, limit, 200_000)
  octants = np.arange(-int(limit * 4 / np.pi), int(limit * 4 / np.pi) + 1)[:, None] * np.pi / 4
  near = (octants + np.array([-1e-4, 0., 1e-4])).ravel()
  return np.concatenate([uniform, near[np.abs(near) <= limit], [0., -0.]]).astype(np.float32)


@pytest.mark.parametrize('limit', [1., 320., 8192.])
def test_sin_and_cos_are_within_float32_rounding_of_the_exact_values(limit):
  x = _samples(limit)
  sin, cos = (np.asarray(v) for v in jax.jit(trig.sin_cos)(x))
  exact = x.astype(np.float64)
  # Two float32 ulps of 1 (1.2e-7): XLA's own sin is within one of the exact value here.
  assert np.max(np.abs(sin - np.sin(exact))) < 1.2e-7
  assert np.max(np.abs(cos - np.cos(exact))) < 1.2e-7


def test_sin_and_cos_are_within_float32_rounding_in_every_binade_up_to_the_largest_float32():
  largest = float(np.finfo(np.float32).max)
  sin_cos = jax.jit(trig.sin_cos)
  for exponent in range(-20, 128):  # Binade [2^e, 2^(e+1)) of both signs per call, so each is judged on its own.
    x = np.minimum(RNG.uniform(1., 2., 2000) * 2.**exponent, largest) * RNG.choice([-1., 1.], 2000)
    x = np.concatenate([x, [2.**exponent, np.minimum(2.**(exponent + 1), largest)]]).astype(np.float32)
    sin, cos = (np.asarray(v) for v in sin_cos(x))
    exact = x.astype(np.float64)
    assert np.max(np.abs(sin - np.sin(exact))) < 1.2e-7, exponent
    assert np.max(np.abs(cos - np.cos(exact))) < 1.2e-7, exponent


def test_sin_and_cos_are_within_float32_rounding_for_every_float32_in_the_binade_below_the_exact_limit():
  """Every float32 of [EXACT_SIN_LIMIT / 2, EXACT_SIN_LIMIT): the reduction's largest octants, where its error
  grows (a few values a binade err above the bound once the limit is too high: sampling misses them)."""
  low, high = (np.float32(v).view(np.int32) for v in (trig.EXACT_SIN_LIMIT / 2, trig.EXACT_SIN_LIMIT))
  x = np.arange(low, high, dtype=np.int32).view(np.float32)
  x = np.concatenate([x, -x[::7]])  # Both signs (odd and even functions of |x|).
  sin, cos = (np.asarray(v) for v in jax.jit(trig.sin_cos)(x))
  exact = x.astype(np.float64)
  assert np.max(np.abs(sin - np.sin(exact))) < 1.2e-7
  assert np.max(np.abs(cos - np.cos(exact))) < 1.2e-7


def test_one_large_element_does_not_spoil_the_others():
  x = np.concatenate([_samples(8192.)[:5000], [np.float32(3e38), np.float32(-1e9)]]).astype(np.float32)
  sin, cos = (np.asarray(v) for v in jax.jit(trig.sin_cos)(x))
  np.testing.assert_allclose(sin, np.sin(x.astype(np.float64)), rtol=0, atol=1.2e-7)
  np.testing.assert_allclose(cos, np.cos(x.astype(np.float64)), rtol=0, atol=1.2e-7)


def test_sin_and_cos_of_non_finite_values_are_nan_like_xla():
  sin, cos = trig.sin_cos(jnp.array([np.inf, -np.inf, np.nan], jnp.float32))
  assert np.all(np.isnan(sin)) and np.all(np.isnan(cos))


def test_derivatives_are_cos_and_minus_sin():
  x = jnp.asarray(_samples(50.)[:2000])
  d_sin = jax.vmap(jax.grad(trig.sin))(x)
  d_cos = jax.vmap(jax.grad(lambda v: trig.sin_cos(v)[1]))(x)
  np.testing.assert_allclose(d_sin, np.cos(np.asarray(x, np.float64)), atol=1.2e-7)
  np.testing.assert_allclose(d_cos, -np.sin(np.asarray(x, np.float64)), atol=1.2e-7)


@pytest.mark.parametrize('period', [100. * np.pi, 2. * np.pi, 1.])
def test_remainder_equals_xla_bit_for_bit_in_every_binade(period):
  limit = trig.EXACT_QUOTIENT * np.float32(period)  # Where remainder takes its fast path (below: all of x).
  binades = [RNG.uniform(-1., 1., 20_000) * 2.**e for e in range(-20, int(np.log2(limit)) + 1)]
  multiples = RNG.integers(-trig.EXACT_QUOTIENT, trig.EXACT_QUOTIENT, 20_000) * np.float64(np.float32(period))
  multiples = multiples.astype(np.float32)
  x = np.concatenate(binades + [multiples, *(np.nextafter(multiples, np.float32(to)) for to in (np.inf, -np.inf))])
  x = x.astype(np.float32)
  x = x[(np.abs(x) >= np.finfo(np.float32).tiny) & (np.abs(x) < limit)]  # XLA flushes subnormals to zero.
  ours = np.asarray(jax.jit(lambda v: trig.remainder(v, period))(x))
  xla = np.asarray(jax.jit(lambda v: jnp.remainder(v, period))(x))
  np.testing.assert_array_equal(ours, xla)


def test_remainder_beyond_the_exact_quotients_falls_back_to_xla():
  x = jnp.array([1e12, -3e15, 7.5, np.inf, np.nan], jnp.float32)
  np.testing.assert_array_equal(trig.remainder(x, 100. * np.pi), jnp.remainder(x, 100. * np.pi))
