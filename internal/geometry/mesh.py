"""A mesh of a trained density field: density on a grid inside bounds, slab by slab, marching cubes, vertex colours.

Host memory grows with resolution^2, not resolution^3: the grid is evaluated SLAB z-planes at a time (chunks of
points through the compiled field), marching cubes runs on each slab (one plane shared with the next), and only
the surface is kept; the vertices that two slabs share are merged. host_bytes and the field's compiled size give
what a resolution and a chunk need before any work. Each grid point is queried as a Gaussian the size of its cell
(variance cell^2 / 12 per axis, a uniform cell's) by mip-NeRF, as a point by NeRF, without density noise.
Vertex colours: the radiance at the vertex seen from outside along its normal (view direction = -normal).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from skimage import measure

from internal.models import freq_schedule
from internal.run import out_of_memory

SLAB = 32  # z-planes evaluated and meshed at a time.
# Host bytes per grid point of a slab while it is evaluated and meshed (its coordinates, the points, the density,
# marching cubes' work); tests/test_mesh.py measures the peak against it.
HOST_BYTES_PER_POINT = 48


class EmptyFieldError(ValueError):
  """The density never crosses the level inside the bounds: there is no surface to write."""


def slab_points(resolution: int) -> int:
  """Grid points of the largest slab of a resolution^3 grid."""
  return resolution**2 * (min(SLAB, resolution - 1) + 1)


def host_bytes(resolution: int) -> int:
  """Host memory meshing a resolution^3 grid needs besides the surface (one slab at a time)."""
  return slab_points(resolution) * HOST_BYTES_PER_POINT


def field_functions(config, model, params, step: int, cell: float, chunk: int):
  """(density(points [chunk,3]) -> [chunk], colour(points [chunk,3], viewdirs [chunk,3]) -> [chunk,3], the bytes
  the larger needs on the device) with the step's masks, compiled for chunk points."""
  masks = freq_schedule.model_masks(config, model, jnp.asarray(step))
  variance = cell**2 / 12.
  variables = {'params': params}
  points = jax.ShapeDtypeStruct((chunk, 3), jnp.float32)
  # Parameters and masks are arguments, not constants folded into the compiled programs.
  density = jax.jit(lambda v, m, p: model.apply(v, p, variance, m[0], method=type(model).density_at)).lower(
      variables, masks, points).compile()
  colour = jax.jit(lambda v, m, p, d: model.apply(v, p, d, variance, *m, method=type(model).colour_at)).lower(
      variables, masks, points, points).compile()
  needed = max(out_of_memory.compiled_size(density), out_of_memory.compiled_size(colour))
  return functools.partial(density, variables, masks), functools.partial(colour, variables, masks), needed


def grid_axes(bounds, resolution: int) -> list:
  """The grid's coordinates along x, y, z: resolution points from bounds[0] to bounds[1] ([2, 3]) each."""
  return [np.linspace(lo, hi, resolution, dtype=np.float32) for lo, hi in np.asarray(bounds, np.float32).T]


def in_chunks(fn, points, chunk: int) -> np.ndarray:
  """fn(points [N, 3]) evaluated chunk rows at a time (the last chunk padded, so one compile)."""
  out = []
  for start in range(0, len(points), chunk):
    piece = points[start:start + chunk]
    padded = np.pad(piece, ((0, chunk - len(piece)), (0, 0)), mode='edge')
    out.append(np.asarray(jax.device_get(fn(padded)))[:len(piece)])
  return np.concatenate(out)


def density_slab(density_fn, axes, z_range, chunk: int) -> np.ndarray:
  """Density [X, Y, Z'] on the grid's z-planes z_range (a range of indices)."""
  xs, ys, zs = np.meshgrid(axes[0], axes[1], axes[2][z_range.start:z_range.stop], indexing='ij')
  points = np.stack([xs, ys, zs], -1).reshape(-1, 3)
  return in_chunks(density_fn, points, chunk).reshape(xs.shape)


def surface_level(config, model) -> float:
  """The default surface density: the density at which one interval of the model's last pass, its samples spread
  evenly over [Config.near, Config.far], lets half the light through (ln 2 / interval): scale-free."""
  return float(np.log(2.) * model.fine_samples_per_ray() / (config.far - config.near))


def march(density_fn, bounds, resolution: int, level: float, chunk: int):
  """(vertices [V, 3], faces [F, 3] int, outward normals [V, 3]) of the level set {density = level}."""
  axes = grid_axes(bounds, resolution)
  spacing = tuple(float(a[1] - a[0]) for a in axes)
  verts, faces, normals, low, high, count = [], [], [], np.inf, -np.inf, 0
  for z0 in range(0, resolution - 1, SLAB):
    volume = density_slab(density_fn, axes, range(z0, min(z0 + SLAB + 1, resolution)), chunk)
    low, high = min(low, float(volume.min())), max(high, float(volume.max()))
    if not volume.min() < level < volume.max():
      continue
    v, f, n, _ = measure.marching_cubes(volume, level, spacing=spacing)
    verts.append(v + np.array([axes[0][0], axes[1][0], axes[2][z0]]))
    faces.append(f + count)
    normals.append(n)  # skimage's normals point down the density: outward.
    count += len(v)
  if not faces:
    side = 'stays below' if high <= level else 'stays above' if low >= level else 'never crosses'
    raise EmptyFieldError(f'the density {side} the level {level:g} inside the bounds (its minimum is {low:.3g}, '
                          f'its maximum {high:.3g}): no surface to mesh; choose a level between them, or check the '
                          'run and the bounds')
  return merge_shared(np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), min(spacing))


def merge_shared(verts, faces, normals, cell: float):
  """Merges vertices closer than cell / 1000 (those on the plane two slabs share); drops faces that collapse."""
  keys = np.round(verts / (cell * 1e-3)).astype(np.int64)
  _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
  faces = inverse.reshape(-1)[faces]
  keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
  return verts[first], faces[keep], normals[first]


def vertex_colours(colour_fn, verts, normals, chunk: int) -> np.ndarray:
  """rgb [V, 3] in [0, 1]: the radiance at each vertex seen along -normal (from outside, head-on)."""
  unit = normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
  rows = np.concatenate([verts, -unit], -1).astype(np.float32)
  rgb = in_chunks(lambda r: colour_fn(r[:, :3], r[:, 3:]), rows, chunk)
  return np.clip(rgb, 0., 1.)
