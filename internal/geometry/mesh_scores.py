"""A mesh of the generated object scene against its exact surfaces: Chamfer distance and coverage, per solid.

The solids are those of scene.json (internal/datasets/scene_generator.py): spheres, boxes and a ground disc. Mesh
to truth (accuracy) is exact: each vertex's distance to the nearest solid surface. Truth to mesh (completeness)
samples each solid's visible surface uniformly (less the ground under a box and a box's bottom face, which no view
sees) and takes each sample's distance to the nearest vertex. A solid the mesh misses shows as a low coverage: the
fraction of its samples within COVERAGE_DISTANCE of a vertex. Chamfer distance alone hides it: dropping a badly
meshed solid lowers the mean distance of the vertices left.
"""

import numpy as np
from scipy.spatial import cKDTree

COVERAGE_DISTANCE = .1  # World units: 1/30 of the object scene's 3-unit ground disc, 2 cells of a 64^3 grid.
SAMPLES_PER_SOLID = 4000
TOUCHING = 1e-2         # Surface points this close to two solids lie where they touch, hidden from every view.


def solid_distance(solid: dict, points: np.ndarray) -> np.ndarray:
  """Distance [N] of points [N, 3] to the surface of one solid of scene.json (sphere, box or disc), exact."""
  if solid['shape'] == 'sphere':
    return np.abs(np.linalg.norm(points - solid['centre'], axis=-1) - solid['radius'])
  if solid['shape'] == 'box':
    q = np.abs((points - solid['centre']) @ np.array(solid['rotation'])) - np.array(solid['half'])
    return np.abs(np.linalg.norm(np.maximum(q, 0.), axis=-1) + np.minimum(q.max(-1), 0.))
  normal = np.array(solid['normal'])
  height = points @ normal - solid['offset']
  radial = np.linalg.norm(points - np.outer(height + solid['offset'], normal), axis=-1)
  return np.hypot(height, np.maximum(radial - _disc_radius(solid), 0.))


def _disc_radius(solid: dict) -> float:
  if solid['radius'] is None:
    raise ValueError(f'the {solid["kind"]} plane is unbounded: only the object scene\'s solids can be scored')
  return solid['radius']


def surface_samples(solid: dict, rng: np.random.Generator, count: int = SAMPLES_PER_SOLID) -> np.ndarray:
  """Points [count, 3] uniform on a solid's surface (a box's faces by their area)."""
  if solid['shape'] == 'sphere':
    d = rng.normal(size=(count, 3))
    return np.array(solid['centre']) + solid['radius'] * d / np.linalg.norm(d, axis=-1, keepdims=True)
  if solid['shape'] == 'box':
    half = np.array(solid['half'])
    face_area = np.prod(half) / half  # Of the two faces normal to each axis, up to a constant.
    axis = rng.choice(3, count, p=face_area / face_area.sum())
    u = rng.uniform(-1., 1., (count, 3))
    u[np.arange(count), axis] = rng.choice([-1., 1.], count)
    return np.array(solid['centre']) + (u * half) @ np.array(solid['rotation']).T
  r, a = _disc_radius(solid) * np.sqrt(rng.uniform(size=count)), rng.uniform(0., 2. * np.pi, count)
  axes = np.array(solid['axes'])
  return solid['offset'] * np.array(solid['normal']) + (r * np.cos(a))[:, None] * axes[0] + (
      r * np.sin(a))[:, None] * axes[1]


def visible_samples(solids: list, rng: np.random.Generator, count: int = SAMPLES_PER_SOLID) -> list:
  """Per solid, points [n_i, 3] on its surface less those where it touches another solid (within TOUCHING)."""
  out = []
  for i, solid in enumerate(solids):
    points = surface_samples(solid, rng, count)
    others = [solid_distance(other, points) for j, other in enumerate(solids) if j != i]
    out.append(points[~np.any(np.array(others) < TOUCHING, 0)] if others else points)
  return out


def solid_name(solid: dict, index: int) -> str:
  """'ground', 'sphere 1 (r 0.45)', 'box 2', ...: a solid's kind or shape, index and size."""
  if solid['kind'] != 'object':
    return solid['kind']
  return f'{solid["shape"]} {index}' + (f' (r {solid["radius"]:.2f})' if solid['shape'] == 'sphere' else '')


def score(verts: np.ndarray, solids: list, seed: int = 0) -> dict:
  """Distances of a mesh's vertices [V, 3] (V >= 1) to the solids and back, overall and per solid.

  {'accuracy', 'completeness', 'chamfer', 'solids': {name: {'accuracy' (of the vertices nearest it; None if
  none), 'completeness', 'chamfer', 'coverage', 'vertices'}}}; chamfer = (accuracy + completeness) / 2.
  """
  samples = visible_samples(solids, np.random.default_rng(seed))
  to_solids = np.stack([solid_distance(solid, verts) for solid in solids])  # [S, V]
  nearest = to_solids.argmin(0)
  tree = cKDTree(verts)
  to_mesh = [tree.query(points)[0] for points in samples]
  per_solid = {}
  for i, solid in enumerate(solids):
    own = to_solids[i, nearest == i]
    accuracy = float(own.mean()) if own.size else None
    completeness = float(to_mesh[i].mean())
    per_solid[solid_name(solid, i)] = {
        'accuracy': accuracy, 'completeness': completeness,
        'chamfer': None if accuracy is None else (accuracy + completeness) / 2.,
        'coverage': float(np.mean(to_mesh[i] <= COVERAGE_DISTANCE)), 'vertices': int(own.size)}
  accuracy, completeness = float(to_solids.min(0).mean()), float(np.concatenate(to_mesh).mean())
  return {'accuracy': accuracy, 'completeness': completeness, 'chamfer': (accuracy + completeness) / 2.,
          'coverage_distance': COVERAGE_DISTANCE, 'solids': per_solid}
