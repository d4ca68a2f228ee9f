"""Tests of internal/models/sampling.py: stratified endpoints, blur, inverse-CDF resampling."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.models import sampling

sample_pdf = jax.jit(sampling.sample_pdf, static_argnums=3)  # one compile per shape, also checks jit
resample_t_vals = jax.jit(sampling.resample_t_vals)


def _near_far(batch, near=2., far=6.):
  """(near [B,1], far [B,1]) filled with constants."""
  return jnp.full((batch, 1), near), jnp.full((batch, 1), far)


def test_stratified_deterministic_is_linspace():
  near, far = jnp.array([[2.], [0.]]), jnp.array([[6.], [1.]])
  t = sampling.stratified_t_vals(None, near, far, 4)
  np.testing.assert_allclose(t, [[2., 3., 4., 5., 6.], [0., .25, .5, .75, 1.]], rtol=1e-6)
  np.testing.assert_array_equal(t, sampling.stratified_t_vals(None, near, far, 4))


def test_stratified_jitter_sorted_within_midpoints():
  near, far = _near_far(512)
  t = np.asarray(sampling.stratified_t_vals(jax.random.PRNGKey(0), near, far, 16))
  base = np.linspace(2., 6., 17)
  mids = 0.5 * (base[1:] + base[:-1])
  lower, upper = np.r_[2., mids], np.r_[mids, 6.]
  assert t.shape == (512, 17)
  assert np.all(np.diff(t, axis=-1) >= 0) and np.all(t >= 2.) and np.all(t <= 6.)
  assert np.all(t >= lower - 1e-6) and np.all(t <= upper + 1e-6)
  # Each endpoint is uniform on [lower, upper]: mean at the centre, spread over the whole range.
  np.testing.assert_allclose(t.mean(0), 0.5 * (lower + upper), atol=0.02)
  assert np.all(t.max(0) - t.min(0) > 0.95 * (upper - lower))
  t2 = sampling.stratified_t_vals(jax.random.PRNGKey(0), near, far, 16)
  np.testing.assert_array_equal(t, t2)
  assert not np.allclose(t, sampling.stratified_t_vals(jax.random.PRNGKey(1), near, far, 16))


def test_blur_weights_hand_example():
  w = jnp.array([[0., 1., 0., 0., 3.]])
  # edge pad: [0, 0,1,0,0,3, 3]; pairwise max: [0,1,1,0,3,3]; pairwise mean: [.5,1,.5,1.5,3].
  np.testing.assert_allclose(sampling.blur_weights(w, 0.01), [[.51, 1.01, .51, 1.51, 3.01]], rtol=1e-6)


def _bin_fractions(samples, bins):
  """Fraction of samples [N] in each bin of bins [S+1]."""
  counts, _ = np.histogram(samples, bins=bins)
  return counts / counts.sum()


def test_sample_pdf_deterministic_follows_weights():
  bins = jnp.array([[0., 1., 1.5, 4., 5., 8.]])
  weights = jnp.array([[0.1, 0.0, 0.5, 0.3, 0.1]])
  n = 10_000
  s = np.asarray(sample_pdf(None, bins, weights, n))[0]
  assert np.all(np.diff(s) >= 0) and s[0] >= 0. and s[-1] <= 8.
  np.testing.assert_allclose(_bin_fractions(s, np.asarray(bins[0])), weights[0], atol=2. / n)
  # Inside a bin the samples are uniform (piecewise-linear CDF): the quantile at 0.35 lies in bin 2.
  np.testing.assert_allclose(s[int(0.35 * n)], 1.5 + 2.5 * (0.35 - 0.1) / 0.5, atol=1e-3)


def test_sample_pdf_random_chi_square():
  rng_weights = np.random.default_rng(0).random(12) ** 2
  bins = jnp.asarray(np.cumsum(np.r_[1., np.random.default_rng(1).random(12) + 0.1]), jnp.float32)
  batch, n = 2000, 16
  weights = jnp.broadcast_to(jnp.asarray(rng_weights, jnp.float32), (batch, 12))
  s = np.asarray(sample_pdf(jax.random.PRNGKey(3), jnp.broadcast_to(bins, (batch, 13)), weights, n))
  assert np.all(np.diff(s, axis=-1) >= 0)
  assert np.all(s >= bins[0]) and np.all(s <= bins[-1])
  counts, _ = np.histogram(s.ravel(), bins=np.asarray(bins))
  expected = batch * n * rng_weights / rng_weights.sum()
  chi2 = np.sum((counts - expected)**2 / expected)
  assert chi2 < 35., chi2  # 11 degrees of freedom: p(chi2 > 35) < 3e-4 for iid draws
  # Stratification: each sample k lies in the CDF stratum [k/n, (k+1)/n).
  cdf = np.r_[0., np.cumsum(rng_weights) / rng_weights.sum()]
  u = np.interp(s, np.asarray(bins), cdf)
  k = np.arange(n)
  assert np.all(u >= k / n - 1e-5) and np.all(u <= (k + 1) / n + 1e-5)


def test_sample_pdf_all_zero_weights_uniform():
  bins = jnp.array([[2., 3., 5., 6.]])
  s = np.asarray(sample_pdf(None, bins, jnp.zeros((1, 3)), 7))[0]
  assert np.all(np.isfinite(s))
  # A uniform pdf over the bins' mass: each bin gets 1/3 of the probability.
  cdf = np.array([0., 1. / 3, 2. / 3, 1.])
  np.testing.assert_allclose(s, np.interp(np.linspace(0., 1., 7), cdf, np.asarray(bins[0])), atol=1e-4)
  s_rand = sample_pdf(jax.random.PRNGKey(0), bins, jnp.zeros((1, 3)), 7)
  assert np.all(np.isfinite(s_rand))


@pytest.mark.parametrize('key', [None, jax.random.PRNGKey(7)])
def test_resample_properties(key):
  t = sampling.stratified_t_vals(jax.random.PRNGKey(0), *_near_far(64), 32)
  weights = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(1), (64, 32)) * 3.)
  new_t = np.asarray(resample_t_vals(key, t, weights, 0.01))
  assert new_t.shape == (64, 33)
  assert np.all(np.diff(new_t, axis=-1) >= 0)
  assert np.all(new_t >= np.asarray(t[:, :1])) and np.all(new_t <= np.asarray(t[:, -1:]))


def test_resample_follows_blurred_weights():
  """Over many rays, the share of new endpoints in each coarse interval matches the blurred pdf."""
  batch = 4000
  t = jnp.broadcast_to(jnp.linspace(2., 6., 9), (batch, 9))
  weights = jnp.broadcast_to(jnp.array([0., 0., 0.1, 0.8, 0.1, 0., 0., 0.]), (batch, 8))
  new_t = np.asarray(resample_t_vals(jax.random.PRNGKey(2), t, weights, 0.01))
  blurred = np.array([0., 0.05, 0.45, 0.8, 0.45, 0.05, 0., 0.]) + 0.01
  expected = blurred / blurred.sum()
  fractions = _bin_fractions(new_t.ravel(), np.linspace(2., 6., 9))
  np.testing.assert_array_less(np.abs(fractions - expected), 4. * np.sqrt(expected / new_t.size))


def test_resample_stop_gradient_and_single_ray():
  t = sampling.stratified_t_vals(None, *_near_far(1), 8)
  weights = jnp.linspace(0.1, 1., 8)[None]

  def loss(t, w):
    return jnp.sum(resample_t_vals(jax.random.PRNGKey(0), t, w, 0.01) ** 2)

  g_t, g_w = jax.grad(loss, argnums=(0, 1))(t, weights)
  np.testing.assert_array_equal(g_t, np.zeros_like(g_t))
  np.testing.assert_array_equal(g_w, np.zeros_like(g_w))
  new_t = resample_t_vals(None, t, weights, 0.01)
  assert new_t.shape == (1, 9) and np.all(np.isfinite(new_t))


def test_invert_cdf_hand_example():
  cdf = jnp.array([[0., 0., 0.5, 1., 1.]])
  bins = jnp.array([[0., 1., 2., 3., 4.]])
  u = jnp.array([[0., 0.25, 0.5, 0.75, 0.999]])
  np.testing.assert_allclose(sampling.invert_cdf(u, cdf, bins), [[1., 1.5, 2., 2.5, 2.998]], atol=1e-6)


def test_pdf_padding_issue_case():
  """32 bins over [0, 4], weight 1e-6 in bin 9 only, resample padding 0: the two padding rules."""
  t = jnp.linspace(0., 4., 33)[None]
  weights = jnp.zeros((1, 32)).at[0, 9].set(1e-6)
  u = np.linspace(0., 1. - np.finfo(np.float32).eps, 33)
  # Blur: 0.5e-6, 1e-6, 0.5e-6 in bins 8..10 (sum 2e-6 > float32 eps: no released padding), so the
  # released cdf rises 0 -> .25 -> .75 -> 1 over t = 1, 1.125, 1.25, 1.375.
  released = np.asarray(resample_t_vals(None, t, weights, 0.))[0]
  np.testing.assert_allclose(released, np.interp(u, [0., .25, .75, 1.], [1., 1.125, 1.25, 1.375]), atol=1e-6)
  assert released[0] == 1. and released[-1] <= 1.375
  # 'even' (the former rule): sum 2e-6 < 1e-5, so every bin gets 8e-6 / 32 and samples span [0, 4].
  blurred = np.zeros(32)
  blurred[8:11] = [.5e-6, 1e-6, .5e-6]
  padded = blurred + 8e-6 / 32
  cdf = np.r_[0., np.cumsum(padded)[:-1] / padded.sum(), 1.]
  even = np.asarray(sampling.resample_t_vals(None, t, weights, 0., 'even'))[0]
  np.testing.assert_allclose(even, np.interp(u, cdf, np.linspace(0., 4., 33)), atol=1e-5)
  np.testing.assert_allclose(even[-2], 3.84375, atol=1e-5)


def test_released_padding_below_float32_eps():
  """Released rule: a sum below eps gets eps - sum added to every bin; zero rows become uniform."""
  eps = np.finfo(np.float32).eps
  w = jnp.array([[0., 4e-8, 0., 0.], [0., 0., 0., 0.], [0., 1e-6, 0., 0.]])
  np.testing.assert_allclose(sampling.pad_weights(w), [[eps - 4e-8] * 4 + np.array([0., 4e-8, 0., 0.]),
                                                       [eps] * 4, [0., 1e-6, 0., 0.]], rtol=1e-6)
  np.testing.assert_allclose(sampling.pad_weights(w[1:2], 'even'), [[2.5e-6] * 4], rtol=1e-6)
  with pytest.raises(ValueError, match='MipNerfModel.pdf_padding'):
    sampling.pad_weights(w, 'uniform')
