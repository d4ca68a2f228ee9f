"""The Rays bundle: a pytree of seven fields in a fixed order, and map_rays over every field."""

import jax
import numpy as np

from internal import rays as rays_lib


def _rays(n):
  """Rays [n, ...] whose field i holds i + 10 * row (3 columns for the first three fields, 1 for the rest)."""
  return rays_lib.Rays(*[np.full((n, 3 if i < 3 else 1), i, np.float32) + 10. * np.arange(n)[:, None]
                         for i in range(7)])


def test_fields_in_order_and_a_pytree():
  rays = _rays(2)
  assert rays_lib.Rays._fields == ('origins', 'directions', 'viewdirs', 'radii', 'lossmult', 'near', 'far')
  leaves = jax.tree.leaves(rays)
  assert [float(x[1, 0]) for x in leaves] == [10., 11., 12., 13., 14., 15., 16.]
  doubled = jax.tree.map(lambda x: 2 * x, rays)
  assert isinstance(doubled, rays_lib.Rays) and float(doubled.far[1, 0]) == 32.


def test_map_rays_reshapes_and_indexes_every_field():
  rays = rays_lib.map_rays(lambda x: x.reshape(2, 3, x.shape[-1]), _rays(6))
  assert isinstance(rays, rays_lib.Rays)
  assert rays.origins.shape == (2, 3, 3) and rays.near.shape == (2, 3, 1)
  np.testing.assert_array_equal(rays.origins[1, 2], [50., 50., 50.])  # Row 5 of the flat bundle.
  picked = rays_lib.map_rays(lambda x: x[:, 1], rays)
  np.testing.assert_array_equal(picked.radii[:, 0], [13., 43.])
