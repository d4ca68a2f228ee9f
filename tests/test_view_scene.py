"""The viewer's scene (tools/view/scene.py, runs.Run's cameras) drawn into a stand-in for viser's scene: frustums where
the cameras are, looking where their rays look, with camera refinement the given and the refined cameras apart and
the test cameras carried into the training frame; the render path through its frames; the points a PLY holds."""

import dataclasses

import gin
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import random

from internal import config_loader
from internal import datasets
from internal.cameras import algebra
from internal.evaluation import camera_evaluation
from internal.geometry import ply
from internal.training import camera_refinement, train_step
from test_checkpoints import DEMO, TINY
from tools.view import cameras, runs, scene


class FakeScene:
  """Records what viser's scene API is asked to draw."""

  def __init__(self):
    self.frustums, self.splines, self.clouds = {}, {}, {}

  def add_camera_frustum(self, name, **kwargs):
    self.frustums[name] = kwargs
    return name

  def add_spline_catmull_rom(self, name, positions, **kwargs):
    self.splines[name] = np.asarray(positions)
    return name

  def add_point_cloud(self, name, points, colors, **kwargs):
    self.clouds[name] = (points, colors)
    return name


class FakeServer:
  def __init__(self):
    self.scene = FakeScene()


@pytest.fixture(name='refining_run', scope='module')
def fixture_refining_run(tmp_path_factory):
  """A runs.Run of the tiny object scene with camera refinement, its corrections set to a few degrees and a shift
  (random weights: no training needed to draw cameras)."""
  gin.clear_config()
  config = config_loader.load_config([DEMO], TINY + [f"Config.data_dir = '{tmp_path_factory.mktemp('scene')}'",
                                                     'Config.optimize_cameras = True',
                                                     'Config.generated_size = (16, 20)'])
  train_set, test_set = datasets.load_dataset('train', config), datasets.load_dataset('test', config)
  state_cameras = camera_refinement.init(config, train_set)
  free = np.random.default_rng(0).normal(scale=.05, size=state_cameras.free.shape).astype(np.float32)
  state_cameras = state_cameras.replace(free=jnp.asarray(free))
  example = jax.tree.map(lambda x: x[0, 0, :8], train_set.rays)
  model, state = train_step.create_train_state(config, random.PRNGKey(0), example, state_cameras)
  return runs.Run(config, 'refining', model, state, train_set, test_set)


def centre_directions(dataset) -> np.ndarray:
  """[N,3] the world direction of each view's centre pixel, from its loaded rays."""
  return np.asarray(dataset.rays.viewdirs[:, dataset.height // 2, dataset.width // 2], np.float64)


def test_frustums_stand_where_the_cameras_are_and_look_where_their_rays_look(refining_run):
  server = FakeServer()
  groups = scene.draw(server, [refining_run], None)
  frustums = server.scene.frustums
  train = refining_run.train_set
  assert len(groups['given cameras']) == len(groups['training cameras']) == len(train.ids)
  given = [frustums[name] for name in groups['given cameras']]
  np.testing.assert_allclose([f['position'] for f in given], train.camtoworlds[:, :, 3], atol=1e-6)
  looks = np.array([algebra.quaternion_to_rotation(f['wxyz'])[:, 2] for f in given])  # OpenCV: +z looks ahead.
  directions = centre_directions(train)
  assert np.all(np.sum(looks * directions, -1) / np.linalg.norm(directions, axis=-1) > .99)
  assert all(f['image'] is None for f in given)
  refined = [frustums[name] for name in groups['training cameras']]
  expected = camera_refinement.refined_cameras(refining_run.state.cameras, np.asarray(train.camtoworlds, np.float64))
  np.testing.assert_allclose([f['position'] for f in refined], expected[:, :, 3], atol=1e-6)
  assert np.min(np.linalg.norm(expected[:, :, 3] - train.camtoworlds[:, :, 3], axis=-1)) > 1e-3  # Apart.
  assert all(f['image'].dtype == np.uint8 and f['image'].shape[2] == 3 for f in refined)  # With their photos.
  fov = cameras.field_of_view(train.pixtocams[0], train.height)
  assert refined[0]['fov'] == pytest.approx(fov) and refined[0]['aspect'] == pytest.approx(train.width / train.height)


def test_test_cameras_are_carried_into_the_training_frame_as_evaluation_carries_them(refining_run):
  server = FakeServer()
  groups = scene.draw(server, [refining_run], None)
  shown = np.array([server.scene.frustums[name]['position'] for name in groups['test cameras']])
  reference = camera_evaluation.reference_cameras(refining_run.config, refining_run.train_set)
  trained = camera_evaluation.training_cameras(refining_run.train_set, refining_run.state.cameras, reference)
  carried = camera_evaluation.test_similarity(trained).cameras(refining_run.test_set.camtoworlds)
  np.testing.assert_allclose(shown, carried[:, :, 3], atol=1e-6)
  assert not np.allclose(shown, refining_run.test_set.camtoworlds[:, :, 3], atol=1e-4)


def test_the_render_path_passes_through_its_frames_centres(refining_run):
  server = FakeServer()
  scene.draw(server, [refining_run], None)
  path = server.scene.splines['/render path']
  radii = np.linalg.norm(path[:, :2], axis=-1)  # The object rig's orbit: one radius and height about the z axis.
  np.testing.assert_allclose(radii, radii.mean(), rtol=1e-3)
  np.testing.assert_allclose(path[:, 2], path[0, 2], atol=1e-3)


def test_points_come_from_a_ply_and_a_file_that_is_none_is_named(refining_run, tmp_path):
  cloud = tmp_path / 'cloud.ply'
  points = np.random.default_rng(0).normal(size=(50, 3)).astype(np.float32)
  ply.write_points(str(cloud), points, np.full((50, 3), .5))
  read, colours = scene.read_points(str(cloud), refining_run)
  np.testing.assert_array_equal(read, points)
  assert colours.dtype == np.uint8
  server = FakeServer()
  scene.draw(server, [refining_run], (read, colours))
  np.testing.assert_array_equal(server.scene.clouds['/points'][0], points)
  assert scene.read_points('', refining_run) is None  # Not a capture: no points of its own.
  (tmp_path / 'text.ply').write_text('hello')
  with pytest.raises(ValueError, match='--points .*text.ply.* is not a point cloud PLY'):
    scene.read_points(str(tmp_path / 'text.ply'), refining_run)
  with pytest.raises(FileNotFoundError, match='--points .*absent.ply.* does not exist'):
    scene.read_points(str(tmp_path / 'absent.ply'), refining_run)


def test_a_second_run_of_other_training_views_has_its_own_cameras(refining_run):
  other = dataclasses.replace(refining_run.train_set, ids=list(refining_run.train_set.ids)[::-1])
  second = runs.Run(refining_run.config, 'other', refining_run.model, refining_run.state, other,
                    refining_run.test_set)
  server = FakeServer()
  groups = scene.draw(server, [refining_run, second], None)
  assert len(groups["compared run's training cameras"]) == len(other.ids)
