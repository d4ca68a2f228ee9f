"""The depth-prior losses (ranking, patch-wise Pearson, sparse SfM depth) against brute force, finite differences
and their extremes: a constant prior, one valid pixel, inf, a prior that is a monotone transform of the truth."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.losses import depth_pearson
from internal.losses import depth_ranking
from internal.losses import sparse_depth


def _patches(seed, count=3, n=12, holes=True):
  """(rendered depth [P, n], prior [P, n]) with some pixels without prior (0 and non-finite)."""
  rng = np.random.default_rng(seed)
  depth = rng.uniform(2., 6., (count, n)).astype(np.float32)
  prior = rng.uniform(.1, 1., (count, n)).astype(np.float32)
  if holes:
    prior[0, :3] = 0.
    prior[1, 4] = np.inf
    prior[2, 5] = np.nan
  return depth, prior


def _brute_ranking(depth, prior, margin, disparity):
  total, pairs = 0., 0
  for patch in range(depth.shape[0]):
    for i, j in itertools.product(range(depth.shape[1]), repeat=2):
      a, b = float(prior[patch, i]), float(prior[patch, j])
      if not (np.isfinite(a) and np.isfinite(b) and a != 0 and b != 0):
        continue
      if (a > b) if disparity else (a < b):  # Pixel i is nearer than pixel j by the prior.
        total += max(0., float(depth[patch, i]) - float(depth[patch, j]) + margin)
        pairs += 1
  return total / max(pairs, 1)


def _brute_pearson(rendered, prior):
  losses = []
  for r, p in zip(rendered.astype(np.float64), prior.astype(np.float64)):
    valid = np.isfinite(p) & (p != 0)
    if valid.sum() >= 2 and np.ptp(p[valid]) > 0:
      losses.append(1. - np.corrcoef(r[valid], p[valid])[0, 1])
  return np.mean(losses) if losses else 0.


def _finite_difference(fn, x, h=1e-3):
  """Central differences of a scalar fn at x [P, n] (float64 on the host), entry by entry."""
  grad = np.zeros_like(x, np.float64)
  for index in np.ndindex(x.shape):
    up, down = x.astype(np.float64).copy(), x.astype(np.float64).copy()
    up[index] += h
    down[index] -= h
    grad[index] = (float(fn(up.astype(np.float32))) - float(fn(down.astype(np.float32)))) / (2 * h)
  return grad


@pytest.mark.parametrize('disparity', [False, True])
@pytest.mark.parametrize('margin', [0., .3])
def test_ranking_loss_matches_brute_force_over_every_ordered_pair(disparity, margin):
  depth, prior = _patches(0)
  expected = _brute_ranking(depth, prior, margin, disparity)
  assert expected > 0
  assert float(depth_ranking.ranking_loss(depth, prior, margin, disparity)) == pytest.approx(expected, rel=1e-5)


def test_ranking_gradient_matches_finite_differences():
  depth, prior = _patches(1)
  fn = lambda d: depth_ranking.ranking_loss(d, prior, .05, False)
  np.testing.assert_allclose(jax.grad(fn)(depth), _finite_difference(fn, depth), atol=2e-3)


def test_ranking_is_zero_for_any_monotone_transform_of_the_truth_and_positive_against_it():
  truth = np.random.default_rng(2).uniform(1., 5., (4, 16)).astype(np.float32)
  for prior, disparity in ((np.exp(truth), False), (3. * truth + 7., False), (1. / truth**.6, True),
                           (2. + .1 / truth, True)):
    assert float(depth_ranking.ranking_loss(truth, prior, 0., disparity)) == 0.
    assert float(depth_ranking.ranking_loss(-truth, prior, 0., disparity)) > 0.  # The order reversed.


def test_ranking_extremes_constant_prior_one_valid_pixel_and_inf_give_zero_with_finite_gradients():
  depth = np.random.default_rng(3).uniform(2., 6., (2, 9)).astype(np.float32)
  one_valid = np.zeros((2, 9), np.float32)
  one_valid[0, 4] = 1.
  for prior in (np.full((2, 9), .7, np.float32), one_valid, np.full((2, 9), np.inf, np.float32)):
    value, grad = jax.value_and_grad(depth_ranking.ranking_loss)(depth, prior, .1, True)
    assert float(value) == 0. and np.all(np.asarray(grad) == 0.)
  # An inf or nan pixel is a pixel without prior: the same loss as a 0 there.
  _, prior = _patches(4, holes=False)
  holes = prior.copy()
  holes[0, 2], holes[1, 3] = np.inf, np.nan
  zeros = prior.copy()
  zeros[0, 2] = zeros[1, 3] = 0.
  depth = _patches(4)[0]
  assert float(depth_ranking.ranking_loss(depth, holes, .1, False)) == float(
      depth_ranking.ranking_loss(depth, zeros, .1, False))


def test_pearson_loss_matches_brute_force_correlations():
  rendered, prior = _patches(5)
  expected = _brute_pearson(rendered, prior)
  assert float(depth_pearson.pearson_loss(rendered, prior)) == pytest.approx(expected, rel=1e-5, abs=1e-6)


def test_pearson_gradient_matches_finite_differences():
  rendered, prior = _patches(6)
  fn = lambda r: depth_pearson.pearson_loss(r, prior)
  np.testing.assert_allclose(jax.grad(fn)(rendered), _finite_difference(fn, rendered), atol=1e-3)


def test_pearson_ignores_the_priors_scale_and_shift_and_is_zero_for_an_affine_prior():
  rendered, prior = _patches(7)
  base = float(depth_pearson.pearson_loss(rendered, prior))
  valid = np.isfinite(prior) & (prior != 0)
  for scale, shift in ((1e-5, 0.), (1e5, 3e5), (2., -.5)):
    moved = np.where(valid, prior * scale + shift, prior).astype(np.float32)
    assert float(depth_pearson.pearson_loss(rendered, moved)) == pytest.approx(base, rel=1e-4)
  assert float(depth_pearson.pearson_loss(rendered, 4. * rendered + 1.)) == pytest.approx(0., abs=1e-5)
  assert float(depth_pearson.pearson_loss(rendered, -rendered)) == pytest.approx(2., abs=1e-5)


def test_pearson_of_a_monotone_transform_is_small_not_zero():
  truth = np.linspace(1., 5., 32, dtype=np.float32)[None]
  bent = float(depth_pearson.pearson_loss(truth, np.exp(truth)))  # Monotone, far from affine.
  shuffled = float(depth_pearson.pearson_loss(truth, np.random.default_rng(8).permutation(np.exp(truth[0]))[None]))
  assert 0. < bent < .2 < shuffled


def test_pearson_extremes_give_finite_values_and_gradients():
  rendered, _ = _patches(9, holes=False)
  one_valid = np.zeros_like(rendered)
  one_valid[:, 0] = 1.
  for prior in (np.full_like(rendered, 3.), one_valid, np.full_like(rendered, np.inf)):  # No patch informs.
    value, grad = jax.value_and_grad(depth_pearson.pearson_loss)(rendered, prior)
    assert float(value) == 0. and np.all(np.asarray(grad) == 0.)
  flat = np.full_like(rendered, 4.)  # A flat rendered patch: correlation 0, gradient finite.
  value, grad = jax.value_and_grad(depth_pearson.pearson_loss)(flat, _patches(9)[1])
  assert float(value) == pytest.approx(1.) and np.all(np.isfinite(np.asarray(grad)))
  assert float(depth_pearson.pearson_loss(rendered, np.where(np.arange(12) < 6, np.inf, rendered))) == (
      pytest.approx(0., abs=1e-5))  # The inf half is no prior; the rest equals the rendered values.


def test_sparse_depth_loss_is_the_weighted_mean_squared_error_and_its_gradient():
  rng = np.random.default_rng(10)
  depth, target, weight = (rng.uniform(1., 3., 20).astype(np.float32) for _ in range(3))
  weight[:5] = 0.
  target[5] = np.inf
  used = (weight > 0) & np.isfinite(target)
  expected = np.sum(weight[used] * (depth[used] - target[used])**2) / np.sum(weight[used])
  value, grad = jax.value_and_grad(sparse_depth.sparse_depth_loss)(depth, target, weight)
  assert float(value) == pytest.approx(expected, rel=1e-5)
  expected_grad = np.where(used, 2. * weight * (depth - np.where(used, target, 0.)) / np.sum(weight[used]), 0.)
  np.testing.assert_allclose(grad, expected_grad, rtol=1e-5, atol=1e-7)


def test_sparse_depth_extremes_no_point_and_one_point():
  depth = jnp.array([1., 2., 3.])
  value, grad = jax.value_and_grad(sparse_depth.sparse_depth_loss)(depth, jnp.array([np.inf, 0., 5.]),
                                                                    jnp.array([1., 0., 0.]))
  assert float(value) == 0. and np.all(np.asarray(grad) == 0.)
  value = sparse_depth.sparse_depth_loss(depth, jnp.array([0., 0., 5.]), jnp.array([0., 0., 1e-3]))
  assert float(value) == pytest.approx(4.)  # One point: its squared error, whatever its weight.
