"""Tests of internal/models/volume_render.py against a brute-force loop and closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.models import volume_render

render = jax.jit(volume_render.volumetric_rendering, static_argnums=(4, 5))  # one compile per shape


def _brute_force(rgb, density, t_vals, directions, white_background):
  """Front-to-back compositing, one ray and one sample at a time (float64)."""
  rgb, density, t_vals, directions = (np.asarray(a, np.float64) for a in (rgb, density, t_vals, directions))
  batch, num = density.shape
  weights, out_rgb, acc = np.zeros((batch, num)), np.zeros((batch, 3)), np.zeros(batch)
  for b in range(batch):
    trans = 1.
    for i in range(num):
      delta = (t_vals[b, i + 1] - t_vals[b, i]) * np.sqrt(np.sum(directions[b]**2))
      alpha = 1. - np.exp(-density[b, i] * delta)
      weights[b, i] = trans * alpha
      trans *= 1. - alpha
      out_rgb[b] += weights[b, i] * rgb[b, i]
      acc[b] += weights[b, i]
    if white_background:
      out_rgb[b] += 1. - acc[b]
  return weights, out_rgb, acc


def _random_inputs(batch=5, num=16, seed=0):
  """Random (rgb [B,S,3], density [B,S], sorted t_vals [B,S+1], directions [B,3])."""
  keys = jax.random.split(jax.random.PRNGKey(seed), 4)
  rgb = jax.random.uniform(keys[0], (batch, num, 3))
  density = jax.random.uniform(keys[1], (batch, num), maxval=3.) ** 2
  t_vals = jnp.sort(jax.random.uniform(keys[2], (batch, num + 1), minval=2., maxval=6.), axis=-1)
  directions = jax.random.normal(keys[3], (batch, 3))
  return rgb, density, t_vals, directions


@pytest.mark.parametrize('white_background', [False, True])
def test_matches_brute_force(white_background):
  rgb, density, t_vals, directions = _random_inputs()
  out = render(rgb, density, t_vals, directions, white_background)
  weights, ref_rgb, ref_acc = _brute_force(rgb, density, t_vals, directions, white_background)
  np.testing.assert_allclose(out['weights'], weights, rtol=2e-5, atol=1e-7)
  np.testing.assert_allclose(volume_render.compute_weights(density, t_vals, directions), weights,
                             rtol=2e-5, atol=1e-7)
  np.testing.assert_allclose(out['rgb'], ref_rgb, rtol=2e-5, atol=1e-6)
  np.testing.assert_allclose(out['acc'], ref_acc, rtol=2e-5, atol=1e-6)
  t_mid = 0.5 * (np.asarray(t_vals[:, 1:]) + np.asarray(t_vals[:, :-1]))
  ref_mean = np.clip((weights * t_mid).sum(-1) / ref_acc, t_vals[:, 0], t_vals[:, -1])
  np.testing.assert_allclose(out['distance_mean'], ref_mean, rtol=1e-5)


def test_white_background_adds_one_minus_acc():
  rgb, density, t_vals, directions = _random_inputs(seed=3)
  black = render(rgb, density * 0.05, t_vals, directions, False)
  white = render(rgb, density * 0.05, t_vals, directions, True)
  assert np.all(np.asarray(black['acc']) < 0.999)
  np.testing.assert_allclose(white['rgb'] - black['rgb'], np.broadcast_to(1. - black['acc'][:, None], (5, 3)),
                             rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize('sigma,near,far,d_scale', [(0.3, 2., 6., 1.), (1.5, 0.5, 2.5, 1.7), (0.05, 1., 9., 0.6)])
def test_constant_density_closed_form(sigma, near, far, d_scale):
  num = 512
  directions = jnp.array([[0.6, 0., 0.8]]) * d_scale  # |d| = d_scale
  t_vals = jnp.linspace(near, far, num + 1)[None]
  rgb = jnp.broadcast_to(jnp.array([0.2, 0.5, 0.9]), (1, num, 3))
  out = render(rgb, jnp.full((1, num), sigma), t_vals, directions, False)
  k, length = sigma * d_scale, far - near
  acc = 1. - np.exp(-k * length)
  np.testing.assert_allclose(out['acc'], [acc], rtol=1e-5)
  np.testing.assert_allclose(out['rgb'], [acc * np.array([0.2, 0.5, 0.9])], rtol=1e-5)
  # Discrete expectation of the interval midpoints (geometric series), exact for this quadrature.
  delta = length / num
  q = np.exp(-k * delta)
  series = q * (1 - num * q**(num - 1) + (num - 1) * q**num) / ((1 - q) * (1 - q**num))
  np.testing.assert_allclose(out['distance_mean'], [near + delta * (series + 0.5)], rtol=2e-5)
  # Continuous expected depth of the truncated exponential, within the quadrature error.
  continuous = near + 1. / k - length * np.exp(-k * length) / acc
  np.testing.assert_allclose(out['distance_mean'], [continuous], rtol=1e-4)
  # Continuous median: the depth where the truncated exponential's CDF reaches 1/2. The released rule
  # puts the cumulative weight of interval i at its midpoint, not its end: half an interval earlier.
  median = near - np.log(1. - 0.5 * acc) / k
  np.testing.assert_allclose(out['distance_median'], [median - 0.5 * delta], rtol=2e-4)


def test_median_and_percentiles_hand_example():
  t_vals = jnp.array([[0., 1., 2., 3., 4.], [0., 1., 2., 3., 4.]])
  directions = jnp.array([[0., 0., 1.], [0., 0., 1.]])
  weights = np.array([[0.1, 0.2, 0.4, 0.3], [0., 0.5, 0.5, 0.]])
  # Density that produces these weights exactly: sigma_i = -log(1 - w_i / T_i) with delta = 1.
  trans = 1. - np.concatenate([np.zeros((2, 1)), np.cumsum(weights, -1)[:, :-1]], -1)
  alpha = np.where(trans > 0, weights / np.maximum(trans, 1e-12), 0.)
  density = jnp.asarray(-np.log1p(-np.minimum(alpha, 1. - 1e-7)), jnp.float32)
  out = render(jnp.zeros((2, 4, 3)), density, t_vals, directions, False, True)
  np.testing.assert_allclose(out['weights'], weights, atol=2e-6)
  # Released rule: cumulative weights [.1, .3, .7, 1] and [0, .5, 1, 1] against the midpoints
  # [.5, 1.5, 2.5, 3.5]: medians 1.5 + (.5 - .3) / .4 = 2 and 1.5. Inverting the step CDF at the
  # interval ends (the former rule) gave 2.5 and 2, half an interval later.
  np.testing.assert_allclose(out['distance_median'], [2., 1.5], atol=1e-4)
  p = [0.5, 0.5 + 0.15 / 0.2, 2., 2.5 + 0.05 / 0.3, 2.5 + 0.25 / 0.3]
  np.testing.assert_allclose(out['distance_percentiles'], [p, [.6, 1., 1.5, 2., 2.4]], atol=1e-4)
  mids = np.array([0.5, 1.5, 2.5, 3.5])
  mean = (weights * mids).sum(-1)
  std = np.sqrt((weights * (mids - mean[:, None])**2).sum(-1))
  np.testing.assert_allclose(out['distance_mean'], mean, atol=1e-4)
  np.testing.assert_allclose(out['distance_std'], std, atol=1e-4)


def test_extras_only_when_asked():
  inputs = _random_inputs(batch=2, num=4)
  base = {'rgb', 'acc', 'weights', 'distance_mean', 'distance_median'}
  assert set(render(*inputs, False, False)) == base
  assert set(volume_render.volumetric_rendering(*inputs, False)) == base
  out = render(*inputs, False, True)
  assert set(out) == base | {'distance_percentiles', 'distance_std'}
  assert out['distance_percentiles'].shape == (2, 5) and out['distance_std'].shape == (2,)
  assert out['rgb'].shape == (2, 3) and out['acc'].shape == (2,) and out['weights'].shape == (2, 4)


@pytest.mark.parametrize('density_value', [0., 1e8])
@pytest.mark.parametrize('white_background', [False, True])
def test_extreme_density_finite_values_and_gradients(density_value, white_background):
  rgb, _, t_vals, directions = _random_inputs(batch=3, num=8, seed=5)
  t_vals = t_vals.at[:, 3].set(t_vals[:, 2])  # a zero-length interval too
  density = jnp.full((3, 8), density_value)

  def loss(rgb, density, t_vals):
    out = render(rgb, density, t_vals, directions, white_background, True)
    return sum(jnp.sum(v) for v in out.values())

  out = render(rgb, density, t_vals, directions, white_background, True)
  assert all(np.all(np.isfinite(v)) for v in out.values())
  if density_value == 0.:
    np.testing.assert_array_equal(out['acc'], np.zeros(3))
    # Released: 0/0 -> 0, clipped to near (the former rule gave far); every cumulative weight is 0,
    # so the percentile interpolation returns the second-to-last midpoint.
    np.testing.assert_array_equal(out['distance_mean'], t_vals[:, 0])
    np.testing.assert_allclose(out['distance_median'], 0.5 * (t_vals[:, -3] + t_vals[:, -2]), rtol=1e-6)
    np.testing.assert_allclose(out['rgb'], np.full((3, 3), float(white_background)))
  else:
    np.testing.assert_allclose(out['acc'], np.ones(3))
    np.testing.assert_allclose(out['rgb'], rgb[:, 0], rtol=1e-6)
    np.testing.assert_allclose(out['distance_mean'], 0.5 * (t_vals[:, 0] + t_vals[:, 1]), rtol=1e-6)
  grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(rgb, density, t_vals)
  assert all(np.all(np.isfinite(g)) for g in grads)


def test_single_ray():
  rgb, density, t_vals, directions = _random_inputs(batch=1, num=8, seed=2)
  out = render(rgb, density, t_vals, directions, True, True)
  weights, ref_rgb, _ = _brute_force(rgb, density, t_vals, directions, True)
  assert out['rgb'].shape == (1, 3) and out['distance_median'].shape == (1,)
  np.testing.assert_allclose(out['rgb'], ref_rgb, rtol=2e-5)
