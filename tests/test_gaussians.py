"""Tests of internal/models/gaussians.py against Monte-Carlo frustums and closed-form moments."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.models import gaussians

NUM_MC = 2_000_000


def _perp_basis(d):
  """Two unit vectors orthogonal to d [3] and to each other."""
  a = np.array([1., 0., 0.]) if abs(d[0]) < 0.9 * np.linalg.norm(d) else np.array([0., 1., 0.])
  e1 = np.cross(d, a)
  e1 /= np.linalg.norm(e1)
  e2 = np.cross(d, e1)
  return e1, e2 / np.linalg.norm(e2)


def _mc_points(rng, d, t0, t1, radius, shape):
  """Uniform points in a cone frustum (radius*t) or a cylinder (radius) around t*d; [N,3] float64."""
  u, v, theta = rng.random(NUM_MC), rng.random(NUM_MC), 2 * np.pi * rng.random(NUM_MC)
  if shape == 'cone':
    t = np.cbrt(t0**3 + u * (t1**3 - t0**3))  # density proportional to t^2
    rho = radius * t * np.sqrt(v)
  else:
    t = t0 + u * (t1 - t0)
    rho = radius * np.sqrt(v)
  e1, e2 = _perp_basis(d)
  offset = rho[:, None] * (np.cos(theta)[:, None] * e1 + np.sin(theta)[:, None] * e2)
  return t[:, None] * d + offset


def _check_against_mc(points, mean, cov_diag):
  """Mean and diagonal covariance within 5 Monte-Carlo standard errors (plus float32 slack)."""
  mc_mean = points.mean(0)
  centred = points - mc_mean
  mc_var = (centred**2).mean(0)
  se_mean = np.sqrt(mc_var / NUM_MC)
  se_var = np.sqrt(((centred**2 - mc_var)**2).mean(0) / NUM_MC)
  np.testing.assert_array_less(np.abs(mean - mc_mean), 5 * se_mean + 1e-6 * np.abs(mc_mean))
  np.testing.assert_array_less(np.abs(cov_diag - mc_var), 5 * se_var + 1e-6 * mc_var)


@pytest.mark.parametrize('shape', ['cone', 'cylinder'])
@pytest.mark.parametrize('t0,t1', [(0.5, 1.7), (0., 1.), (2., 2.3)])
def test_gaussian_matches_monte_carlo(shape, t0, t1):
  rng = np.random.default_rng(0)
  d = np.array([0.3, -1.2, 0.8])
  radius = 0.4
  fn = gaussians.conical_frustum_to_gaussian if shape == 'cone' else gaussians.cylinder_to_gaussian
  mean, cov = fn(jnp.asarray(d, jnp.float32), jnp.array([t0]), jnp.array([t1]), jnp.array([radius]))
  assert mean.shape == cov.shape == (1, 3)
  points = _mc_points(rng, d, t0, t1, radius, shape)
  _check_against_mc(points, np.asarray(mean[0], np.float64), np.asarray(cov[0], np.float64))


def _exact_cone_cov(d, t0, t1, radius):
  """Exact mean and diagonal covariance of a uniform cone frustum (float64, moments of s = t - mu)."""
  mu, h = (t0 + t1) / 2., (t1 - t0) / 2.
  z = 2. * h * mu**2 + 2. * h**3 / 3.  # integral of t^2 over [mu - h, mu + h]
  s1 = (4. * mu * h**3 / 3.) / z
  s2 = (2. * mu**2 * h**3 / 3. + 2. * h**5 / 5.) / z
  r_var = radius**2 * (mu**2 + 2. * mu * s1 + s2) / 4.
  cov = (s2 - s1**2) * d**2 + r_var * (1. - d**2 / np.sum(d**2))
  return (mu + s1) * d, cov


@pytest.mark.parametrize('radius', [0., 0.002, 0.5])
@pytest.mark.parametrize('t0,t1', [(0., 1e-3), (1., 1.0001), (2., 6.), (0.1, 1e3), (10., 10.5)])
def test_cone_matches_exact_moments(t0, t1, radius):
  """The stable float32 form against float64 moments of density t^2 on [t0, t1]."""
  d = np.array([-0.4, 0.2, 1.0])
  t0, t1 = float(np.float32(t0)), float(np.float32(t1))
  mean, cov = gaussians.conical_frustum_to_gaussian(
      jnp.asarray(d, jnp.float32), jnp.array([t0]), jnp.array([t1]), jnp.array([radius]))
  exact_mean, exact_cov = _exact_cone_cov(d, t0, t1, radius)
  np.testing.assert_allclose(mean[0], exact_mean, rtol=1e-5)
  np.testing.assert_allclose(cov[0], exact_cov, rtol=2e-5)


def test_cylinder_closed_form_and_scaling():
  d = jnp.array([[0., 0., 2.]])
  mean, cov = gaussians.cylinder_to_gaussian(d, jnp.array([[1., 3.]]), jnp.array([[2., 5.]]), jnp.array([[0.2]]))
  np.testing.assert_allclose(mean[0], [[0, 0, 3.], [0, 0, 8.]], rtol=1e-6)
  np.testing.assert_allclose(cov[0], [[0.01, 0.01, 4. / 12], [0.01, 0.01, 16. / 12]], rtol=1e-6)


def test_lift_gaussian_diag():
  d = jnp.array([1., 2., 2.])
  mean, cov = gaussians.lift_gaussian(d, jnp.array([2.]), jnp.array([0.5]), jnp.array([0.1]))
  np.testing.assert_allclose(mean, [[2., 4., 4.]], rtol=1e-6)
  full = 0.5 * np.outer(d, d) + 0.1 * (np.eye(3) - np.outer(d, d) / 9.)
  np.testing.assert_allclose(cov, [np.diag(full)], rtol=1e-6)


def test_lift_gaussian_zero_direction_finite():
  mean, cov = gaussians.lift_gaussian(jnp.zeros(3), jnp.array([1.]), jnp.array([1.]), jnp.array([1.]))
  np.testing.assert_array_equal(mean, np.zeros((1, 3)))
  np.testing.assert_allclose(cov, np.ones((1, 3)))


def test_cast_rays_adds_origins_and_uses_intervals():
  key = jax.random.PRNGKey(1)
  origins = jax.random.normal(key, (4, 3))
  directions = jax.random.normal(jax.random.PRNGKey(2), (4, 3))
  radii = jnp.full((4, 1), 0.01)
  t_vals = jnp.sort(jax.random.uniform(key, (4, 9), minval=2., maxval=6.), axis=-1)
  for shape, fn in (('cone', gaussians.conical_frustum_to_gaussian),
                    ('cylinder', gaussians.cylinder_to_gaussian)):
    means, cov = gaussians.cast_rays(t_vals, origins, directions, radii, shape)
    rel, cov_ref = fn(directions, t_vals[:, :-1], t_vals[:, 1:], radii)
    assert means.shape == cov.shape == (4, 8, 3)
    np.testing.assert_allclose(means, rel + origins[:, None], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(cov, cov_ref, rtol=1e-6)


def test_cast_rays_bad_shape():
  with pytest.raises(ValueError, match='MipNerfModel.ray_shape'):
    gaussians.cast_rays(jnp.ones((1, 3)), jnp.zeros((1, 3)), jnp.ones((1, 3)), jnp.ones((1, 1)), 'sphere')


@pytest.mark.parametrize('shape', ['cone', 'cylinder'])
@pytest.mark.parametrize('t_vals', [[2., 2., 3., 3.], [0., 0., 1e-4, 1.], [2., 100., 1e4, 1e4]])
def test_degenerate_intervals_finite_with_gradients(shape, t_vals):
  """Zero-width intervals, near = 0 and far = 1e4: outputs and gradients finite."""
  t = jnp.array([t_vals, t_vals])
  origins = jnp.zeros((2, 3))
  radii = jnp.full((2, 1), 0.001)
  directions = jnp.array([[0.1, -0.2, 1.], [0., 0., 0.]])

  def loss(t, directions):
    means, cov = gaussians.cast_rays(t, origins, directions, radii, shape)
    return jnp.sum(means) + jnp.sum(cov)

  means, cov = gaussians.cast_rays(t, origins, directions, radii, shape)
  assert np.all(np.isfinite(means)) and np.all(np.isfinite(cov))
  assert np.all(np.asarray(cov) >= -1e-3 * np.max(np.abs(cov)))
  g_t, g_d = jax.grad(loss, argnums=(0, 1))(t, directions)
  assert np.all(np.isfinite(g_t)) and np.all(np.isfinite(g_d))
