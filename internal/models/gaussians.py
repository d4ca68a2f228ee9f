"""Gaussian approximations of conical frustums and cylinders along rays (mip-NeRF eq. 7)."""

import jax.numpy as jnp

_EPS = float(jnp.finfo(jnp.float32).eps)


def lift_gaussian(directions, t_mean, t_var, r_var):
  """Lifts 1-D ray statistics [...,S] to 3-D: (mean [...,S,3] rel. origin, cov_diag [...,S,3])."""
  mean = directions[..., None, :] * t_mean[..., None]
  d_sq = directions**2
  d_norm_sq = jnp.maximum(1e-10, jnp.sum(d_sq, axis=-1, keepdims=True))
  perp = 1. - d_sq / d_norm_sq
  cov_diag = t_var[..., None] * d_sq[..., None, :] + r_var[..., None] * perp[..., None, :]
  return mean, cov_diag


def conical_frustum_to_gaussian(directions, t0, t1, base_radius):
  """Stable cone-frustum Gaussian; directions [...,3], t0/t1 [...,S], base_radius [...,1] -> 2x [...,S,3]."""
  mu = (t0 + t1) / 2.
  hw = (t1 - t0) / 2.
  denom = jnp.maximum(_EPS, 3. * mu**2 + hw**2)
  t_mean = mu + (2. * mu * hw**2) / denom
  t_var = hw**2 / 3. - (4. / 15.) * hw**4 * (12. * mu**2 - hw**2) / denom**2
  r_var = base_radius**2 * (mu**2 / 4. + (5. / 12.) * hw**2 - (4. / 15.) * hw**4 / denom)
  return lift_gaussian(directions, t_mean, t_var, r_var)


def cylinder_to_gaussian(directions, t0, t1, radius):
  """Cylinder Gaussian; directions [...,3], t0/t1 [...,S], radius [...,1] -> 2x [...,S,3]."""
  t_mean = (t0 + t1) / 2.
  t_var = (t1 - t0)**2 / 12.
  r_var = radius**2 / 4. * jnp.ones_like(t_mean)
  return lift_gaussian(directions, t_mean, t_var, r_var)


RAY_SHAPES = ('cone', 'cylinder')  # MipNerfModel.ray_shape: conical frustums or cylinders.


def cast_rays(t_vals, origins, directions, radii, ray_shape):
  """Gaussians of the intervals of t_vals [...,S+1] -> (means [...,S,3], cov_diag [...,S,3])."""
  if ray_shape == 'cone':
    gaussian_fn = conical_frustum_to_gaussian
  elif ray_shape == 'cylinder':
    gaussian_fn = cylinder_to_gaussian
  else:
    raise ValueError(f'MipNerfModel.ray_shape = {ray_shape!r}; expected one of {list(RAY_SHAPES)}')
  means, cov_diag = gaussian_fn(directions, t_vals[..., :-1], t_vals[..., 1:], radii)
  return means + origins[..., None, :], cov_diag
