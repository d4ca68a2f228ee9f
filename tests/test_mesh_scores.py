"""Scoring a mesh against the generated object scene's exact surfaces (geometry/mesh_scores.py): distances to each
kind of solid by hand, uniform surface samples, the hidden contact surfaces, Chamfer distance and coverage."""

import numpy as np
import pytest

from internal.datasets import scene_generator
from internal.geometry import mesh_scores

SPHERE = {'shape': 'sphere', 'kind': 'object', 'centre': [0., 0., .5], 'radius': .5}
# A box of half sizes (0.2, 0.1, 0.3) turned 90 degrees about z (its x extent along y), standing on the ground.
BOX = {'shape': 'box', 'kind': 'object', 'centre': [1., 0., .3], 'half': [.2, .1, .3],
       'rotation': [[0., -1., 0.], [1., 0., 0.], [0., 0., 1.]]}
GROUND = {'shape': 'plane', 'kind': 'ground', 'normal': [0., 0., 1.], 'offset': 0., 'radius': 1.5,
          'axes': [[1., 0., 0.], [0., 1., 0.]]}


def test_distances_to_a_sphere_a_turned_box_and_a_disc_by_hand():
  p = np.array([[0., 0., 1.5], [0., 0., .5], [.3, .4, .5]])
  np.testing.assert_allclose(mesh_scores.solid_distance(SPHERE, p), [.5, .5, 0.], atol=1e-12)
  # Outside its long face (along world y after the turn), beyond a corner, and inside nearer its top than its side.
  p = np.array([[1., .5, .3], [1.4, .5, .9], [1., 0., .55]])
  np.testing.assert_allclose(mesh_scores.solid_distance(BOX, p), [.3, np.sqrt(.3**2 + .3**2 + .3**2), .05],
                             atol=1e-12)
  p = np.array([[.3, .4, .2], [0., -2., 0.], [3., 0., -.4]])  # Above the disc, beyond its rim, below and beyond.
  np.testing.assert_allclose(mesh_scores.solid_distance(GROUND, p), [.2, .5, np.hypot(.4, 1.5)], atol=1e-12)


@pytest.mark.parametrize('solid', [SPHERE, BOX, GROUND], ids=['sphere', 'box', 'disc'])
def test_surface_samples_lie_on_the_solid_and_spread_by_area(solid):
  points = mesh_scores.surface_samples(solid, np.random.default_rng(0), 20000)
  assert points.shape == (20000, 3)
  np.testing.assert_allclose(mesh_scores.solid_distance(solid, points), 0., atol=1e-9)
  if solid is BOX:  # The faces normal to the box's own z (0.4 x 0.2 each) hold 0.08 / 0.44 of its area.
    local = (points - solid['centre']) @ np.array(solid['rotation'])
    assert np.mean(np.isclose(np.abs(local[:, 2]), .3)) == pytest.approx(.08 / .44, abs=.01)
  if solid is GROUND:  # Uniform on the disc: half the points within radius 1.5 / sqrt(2).
    assert np.mean(np.linalg.norm(points, axis=-1) < 1.5 / np.sqrt(2.)) == pytest.approx(.5, abs=.01)


def test_the_box_bottom_and_the_ground_under_it_are_not_sampled():
  samples = mesh_scores.visible_samples([GROUND, BOX], np.random.default_rng(0), 20000)
  under_box = mesh_scores.solid_distance(BOX, samples[0]) < mesh_scores.TOUCHING
  assert not under_box.any() and len(samples[0]) == pytest.approx(20000 * (1 - .08 / (np.pi * 1.5**2)), rel=.05)
  assert samples[1][:, 2].min() > mesh_scores.TOUCHING - 1e-9   # No bottom face: 0.04 of 0.44 of the area gone.
  assert len(samples[1]) == pytest.approx(20000 * .40 / .44, rel=.03)


def test_a_perfect_mesh_a_shifted_one_and_a_missing_solid():
  solids = [GROUND, SPHERE, BOX]
  verts = np.concatenate(mesh_scores.visible_samples(solids, np.random.default_rng(1), 3000))
  perfect = mesh_scores.score(verts, solids)
  assert perfect['chamfer'] < .01 and all(s['coverage'] == 1. for s in perfect['solids'].values())
  assert list(perfect['solids']) == ['ground', 'sphere 1 (r 0.50)', 'box 2']
  shifted = mesh_scores.score(verts + [0., 0., .05], solids)   # Up by 0.05: the ground's vertices 0.05 off.
  assert shifted['solids']['ground']['accuracy'] == pytest.approx(.05, abs=1e-3)
  no_box = mesh_scores.score(verts[mesh_scores.solid_distance(BOX, verts) > 1e-6], solids)
  box = no_box['solids']['box 2']
  assert box['vertices'] == 0 and box['accuracy'] is None and box['coverage'] < .5
  # Completeness by brute force: each box sample's distance to the nearest vertex.
  samples = mesh_scores.visible_samples(solids, np.random.default_rng(0))[2]
  left = verts[mesh_scores.solid_distance(BOX, verts) > 1e-6]
  nearest = np.array([np.linalg.norm(left - sample, axis=-1).min() for sample in samples])
  assert box['completeness'] == pytest.approx(nearest.mean(), rel=1e-9)
  assert box['coverage'] == pytest.approx(np.mean(nearest <= mesh_scores.COVERAGE_DISTANCE))


def test_the_forward_scene_has_unbounded_planes_and_is_refused():
  scene, _ = scene_generator.build_scene(scene_generator.scene_params('forward', 0, 8, 10, 1))
  with pytest.raises(ValueError, match='plane is unbounded'):
    mesh_scores.score(np.zeros((1, 3)), scene['solids'])
