"""The ray bundle every loader produces and the model consumes."""

from typing import NamedTuple

import jax


class Rays(NamedTuple):
  """A batch of rays; every field has shape [..., 3] or [..., 1] (a pytree)."""
  origins: jax.Array     # [..., 3]
  directions: jax.Array  # [..., 3], not unit length (camera-frame |z| = 1)
  viewdirs: jax.Array    # [..., 3], encoded by the view-direction branch
  radii: jax.Array       # [..., 1], pixel footprint at unit distance
  lossmult: jax.Array    # [..., 1]
  near: jax.Array        # [..., 1]
  far: jax.Array         # [..., 1]


def map_rays(fn, rays):
  """Applies fn to every field of rays (e.g. reshape or index); returns Rays."""
  return Rays(*[fn(x) for x in rays])
