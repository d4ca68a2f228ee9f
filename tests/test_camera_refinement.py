"""Camera refinement (Config.optimize_cameras): the gauge, the step, exact resumption, two devices, recovery of a
known perturbation, the cameras written after training and the evaluation in the refined frame."""

import dataclasses
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import random

from internal import datasets
from internal.cameras import algebra, alignment, caster, corrections
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, colmap_model
from internal.evaluation import camera_evaluation
from internal.evaluation import evaluate
from internal.pipeline import loop
from internal.run import camera_export
from internal.run import checkpoints
from internal.training import camera_refinement
from internal.training import train_step as ts
from lab import camera_report
from test_checkpoints import ROOT, _leaves, tiny_config

NOISE = ('Config.camera_noise_rotation_deg = 3.', 'Config.camera_noise_translation = 0.03')
REFINE = ('Config.optimize_cameras = True', 'Config.camera_lr_init = 1e-2', 'Config.camera_lr_final = 1e-3')


def test_the_gauge_leaves_no_global_motion_and_is_a_projection():
  rng = np.random.default_rng(0)
  free, centres = rng.normal(size=(5, 6)), rng.normal(size=(5, 3))
  fixed = np.asarray(camera_refinement.gauge_fixed(free, centres, np))
  np.testing.assert_allclose(fixed.mean(0), 0., atol=1e-12)  # No mean rotation, no mean translation.
  offsets = centres - centres.mean(0)
  assert abs(np.sum(fixed[:, 3:] * offsets)) < 1e-12  # No scaling about the centroid.
  np.testing.assert_allclose(camera_refinement.gauge_fixed(fixed, centres, np), fixed, atol=1e-12)
  motion = np.concatenate([np.tile([.1, .2, .3], (5, 1)), np.tile([1., 2., 3.], (5, 1)) + .5 * offsets], 1)
  np.testing.assert_allclose(camera_refinement.gauge_fixed(free + motion, centres, np), fixed, atol=1e-12)
  np.testing.assert_allclose(camera_refinement.gauge_fixed(free[:1], centres[:1], np), 0., atol=1e-12)


def test_the_shared_tilt_is_taken_out_with_the_gauge_and_nothing_else():
  rng = np.random.default_rng(1)
  axes = np.stack([corrections.so3_exp(rng.normal(size=3))[:, :2] for _ in range(6)])  # Own x and y axes [6,3,2].
  free, centres = rng.normal(size=(6, 6)), rng.normal(size=(6, 3))
  fixed = np.asarray(camera_refinement.gauge_fixed(free, centres, np, axes))
  omega = fixed[:, :3]
  np.testing.assert_allclose(omega.sum(0), 0., atol=1e-12)                    # No turn shared in world axes,
  np.testing.assert_allclose(np.einsum('nij,ni->j', axes, omega), 0., atol=1e-12)  # none about own x and y.
  np.testing.assert_allclose(fixed[:, 3:], camera_refinement.gauge_fixed(free, centres, np)[:, 3:], atol=1e-12)
  tilt = np.concatenate([axes @ np.array([.02, -.03]) + np.array([.01, .0, .04]), np.zeros((6, 3))], 1)
  np.testing.assert_allclose(camera_refinement.gauge_fixed(free + tilt, centres, np, axes), fixed, atol=1e-12)
  np.testing.assert_allclose(camera_refinement.gauge_fixed(fixed, centres, np, axes), fixed, atol=1e-12)
  turned = np.asarray(camera_refinement.gauge_fixed(jnp.asarray(free, jnp.float32), jnp.asarray(centres, jnp.float32),
                                                    jnp, jnp.asarray(axes, jnp.float32)))
  np.testing.assert_allclose(turned, fixed, atol=1e-5)
  roll = np.concatenate([np.cross(axes[:, :, 0], axes[:, :, 1]) * .05, np.zeros((6, 3))], 1)  # Own z: kept.
  kept = np.asarray(camera_refinement.gauge_fixed(roll, centres, np, axes))
  assert np.linalg.norm(kept) > .5 * np.linalg.norm(roll[:, :3])


def test_a_step_with_the_shared_tilt_fixed_moves_the_cameras_without_one(scene_dir, tmp_path):
  config, data, model, state, batch = _camera_batch(scene_dir, tmp_path, 'Config.camera_fix_shared_tilt = True')
  new, stats = ts.make_train_step(config, model)(state, batch, random.PRNGKey(1))
  axes = np.asarray(data.camtoworlds, np.float64)[:, :, :2]
  np.testing.assert_allclose(np.asarray(new.cameras.tilt_axes), axes, atol=1e-6)
  omega = np.asarray(camera_refinement.gauge_fixed(new.cameras.free, new.cameras.centres, jnp, new.cameras.tilt_axes))
  assert np.abs(omega).max() > 0 and not bool(stats['skipped'])
  np.testing.assert_allclose(np.einsum('nij,ni->j', axes, omega[:, :3]), 0., atol=1e-6)
  refined = camera_refinement.refined_cameras(new.cameras, np.asarray(data.camtoworlds, np.float64))
  turns = np.einsum('nji,njk->nik', np.asarray(data.camtoworlds, np.float64)[:, :, :3], refined[:, :, :3])
  assert np.abs(turns - np.eye(3)).max() > 0


def _camera_batch(scene_dir, tmp_path, *bindings):
  """(config, dataset, model, CameraTrainState, batch of step 1) of the tiny scene with noise and refinement."""
  config = tiny_config(scene_dir, tmp_path / 'run', *NOISE, *REFINE, *bindings)
  data = datasets.load_dataset('train', config)
  batch = datasets.make_batcher(data, config)(1)
  model, state = ts.create_train_state(config, random.PRNGKey(0), batch.rays,
                                       camera_refinement.init(config, data))
  return config, data, model, state, batch


def test_the_step_moves_the_cameras_only_when_asked(scene_dir, tmp_path):
  config, _, model, state, batch = _camera_batch(scene_dir, tmp_path)
  assert isinstance(state, ts.CameraTrainState) and batch.pixels.view.shape == (config.batch_size,)
  new, stats = ts.make_train_step(config, model)(state, batch, random.PRNGKey(1))
  moved = np.asarray(camera_refinement.gauge_fixed(new.cameras.free, new.cameras.centres))
  assert not bool(stats['skipped']) and np.abs(moved).max() > 0 and float(stats['camera_lr']) > 0
  views = np.unique(batch.pixels.view)  # Views without rays in the batch move only through the gauge.
  assert np.abs(np.asarray(new.cameras.free)[views]).max() > 0
  off = tiny_config(scene_dir, tmp_path / 'off', *NOISE)
  data = datasets.load_dataset('train', off)
  plain = datasets.make_batcher(data, off)(1)
  assert plain.pixels is None
  _, state = ts.create_train_state(off, random.PRNGKey(0), plain.rays)
  assert type(state) is ts.TrainState  # pylint: disable=unidiomatic-typecheck


def test_shifts_in_camera_distances_move_cameras_and_rays_that_many_times_further(scene_dir, tmp_path):
  config, data, _, _, batch = _camera_batch(scene_dir, tmp_path, 'Config.camera_shift_in_distances = True')
  scaled = camera_refinement.init(config, data)
  assert scaled.shift_unit == alignment.camera_distance(data.camtoworlds, data.space) == 4.
  plain = camera_refinement.init(dataclasses.replace(config, camera_shift_in_distances=False), data)
  assert plain.shift_unit == 1.
  free = jnp.asarray(np.random.default_rng(0).normal(scale=1e-2, size=(len(data.ids), 6)), jnp.float32)
  given = np.asarray(data.camtoworlds, np.float64)
  moved = [camera_refinement.refined_cameras(state.replace(free=free), given) for state in (plain, scaled)]
  np.testing.assert_array_equal(moved[0][:, :, :3], moved[1][:, :, :3])  # The turns are the same.
  np.testing.assert_allclose(moved[1][:, :, 3] - given[:, :, 3], 4. * (moved[0][:, :, 3] - given[:, :, 3]), rtol=1e-9)
  origins = [np.asarray(camera_refinement.corrected_batch(state, free, batch).rays.origins, np.float64)
             for state in (plain, scaled)]
  loaded = np.asarray(batch.rays.origins, np.float64)
  np.testing.assert_allclose(origins[1] - loaded, 4. * (origins[0] - loaded), rtol=1e-4, atol=1e-5)


def test_resumed_refinement_equals_uninterrupted_refinement_and_writes_its_cameras(tmp_path, scene_dir):
  bindings = (*NOISE, *REFINE, 'Config.max_steps = 8', 'Config.checkpoint_every = 4')
  first = loop.train(tiny_config(scene_dir, tmp_path / 'resumed', *bindings), stop_at_step=4)
  resumed = loop.train(tiny_config(scene_dir, tmp_path / 'resumed', *bindings)).state
  straight = loop.train(tiny_config(scene_dir, tmp_path / 'straight', *bindings)).state
  assert isinstance(resumed, ts.CameraTrainState)
  for a, b in zip(_leaves(resumed), _leaves(straight)):
    np.testing.assert_array_equal(a, b)
  assert not np.array_equal(np.asarray(first.state.cameras.free), np.asarray(resumed.cameras.free))
  config = tiny_config(scene_dir, tmp_path / 'straight', *bindings)
  data = datasets.load_dataset('train', config)
  _, restored = checkpoints.restore_model(config, str(tmp_path / 'straight'),  # As render.py and tools.mesh do.
                                          jax.tree.map(lambda x: x[0, 0, :8], data.rays))
  np.testing.assert_array_equal(restored.cameras.free, straight.cameras.free)
  refined = camera_refinement.refined_cameras(straight.cameras, data.camtoworlds)
  folder = os.path.join(tmp_path / 'straight', camera_export.FOLDER)  # The cameras as COLMAP reads them.
  record = json.loads(open(os.path.join(folder, 'cameras.json')).read())
  np.testing.assert_allclose(record['refined'], refined, atol=1e-12)
  model = colmap_model.read_model(os.path.join(folder, 'refined'))
  for k, image in sorted(model.images.items()):  # World-to-camera poses in OpenCV axes (the loader's are OpenGL).
    np.testing.assert_allclose(colmap_model.camera_center(image), refined[k - 1, :, 3], atol=1e-7)
    np.testing.assert_allclose(algebra.quaternion_to_rotation(image.qvec).T,
                               refined[k - 1, :, :3] @ np.diag([1., -1., -1.]), atol=1e-7)
  pycolmap = pytest.importorskip('pycolmap')
  assert pycolmap.Reconstruction(os.path.join(folder, 'refined')).num_reg_images() == len(data.ids)
  runs = [str(tmp_path / name) for name in ('straight', 'resumed')]  # Two runs in one call: each its own settings.
  assert camera_report.main(['--out', str(tmp_path / 'report'), '--runs', *runs]) == 0
  assert sorted(os.listdir(tmp_path / 'report')) == ['cameras_resumed.png', 'cameras_straight.png']


SHARDED = textwrap.dedent('''
    import os, sys, pathlib
    sys.path.insert(0, os.getcwd()); sys.path.insert(0, os.path.join(os.getcwd(), 'tests'))
    import jax, numpy as np
    from jax import random
    import test_camera_refinement as t
    from internal.run import sharding
    from internal.training import train_step as ts
    assert len(jax.devices()) == 2
    results = []
    for mesh in (None, sharding.data_mesh()):
      config, _, model, state, batch = t._camera_batch(pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2]),
                                                       "Config.generated_rig = 'forward'")
      if mesh is not None:
        state, batch = sharding.replicate(state, mesh), sharding.shard_batch(batch, mesh)
      step = ts.make_train_step(config, model)
      for _ in range(3):
        state, stats = step(state, batch, random.PRNGKey(1))
      results.append((float(stats['loss']), jax.tree.map(np.asarray, (state.params, state.cameras.free))))
    (loss1, p1), (loss2, p2) = results
    assert abs(loss1 - loss2) < 1e-5, (loss1, loss2)
    diff = max(float(np.max(np.abs(a - b))) for a, b in zip(jax.tree.leaves(p1), jax.tree.leaves(p2)))
    assert diff < 1e-5, diff
    assert np.abs(p1[1]).max() > 0
    print('OK', loss1, loss2, diff)
''')


def test_two_devices_refine_as_one(scene_dir, tmp_path):
  env = dict(os.environ, XLA_FLAGS='--xla_force_host_platform_device_count=2', JAX_PLATFORMS='cpu')
  result = subprocess.run([sys.executable, '-c', SHARDED, str(scene_dir) + '_forward', str(tmp_path)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
  assert result.returncode == 0, result.stdout + result.stderr
  assert 'OK' in result.stdout


@pytest.mark.slow  # 26 s a call in the clean-clone run (results/ci/run.log).
def test_a_known_perturbation_of_one_camera_is_mostly_undone(scene_dir, tmp_path):
  """8 views of the tiny scene, one turned by 2.9 degrees and moved: 300 steps with fixed cameras, then 600 of
  joint refinement (from the start, the rough first model pulls the exact cameras too)."""
  config = tiny_config(scene_dir, tmp_path / 'run', *REFINE, 'Config.freq_reg = False', 'Config.max_steps = 900',
                       'Config.batch_size = 256', 'Config.camera_lr_init = 5e-2', 'Config.camera_lr_final = 5e-3')
  clean = datasets.load_dataset('train', config)
  turn, shift = corrections.so3_exp(np.array([[0., .05, 0.]])), np.array([[0., .1, 0.]])
  first = base.subset(clean, [0])
  moved = corrections.corrected_image_rays(first.rays, first.cameras, turn, shift, clean.space)
  rays = type(clean.rays)(*[np.concatenate([m, x[1:]]) for m, x in zip(moved, clean.rays)])
  c2w = np.concatenate([corrections.corrected_cameras(clean.camtoworlds[:1], turn, shift), clean.camtoworlds[1:]])
  perturbed = dataclasses.replace(clean, rays=rays, camtoworlds=c2w.astype(np.float32))
  batcher = datasets.make_batcher(perturbed, config)
  fixed = dataclasses.replace(config, optimize_cameras=False)
  model, state = ts.create_train_state(fixed, random.PRNGKey(0), batcher(0).rays)
  step = ts.make_train_step(fixed, model)
  for k in range(1, 301):
    state, _ = step(state, batcher(k)._replace(pixels=None), random.PRNGKey(1))
  state = ts.CameraTrainState(step=state.step, params=state.params, opt_state=state.opt_state,
                              cameras=camera_refinement.init(config, perturbed))
  step = ts.make_train_step(config, model)
  for k in range(301, 901):
    state, _ = step(state, batcher(k), random.PRNGKey(1))
  before = alignment.errors(perturbed.camtoworlds, clean.camtoworlds, 4.)
  after = alignment.errors(camera_refinement.refined_cameras(state.cameras, perturbed.camtoworlds),
                                  clean.camtoworlds, 4.)
  assert before['rotation_deg'][0] > 2.3
  # Measured: 2.6 -> 1.19 degrees, the exact views within 0.6 (this model's floor; with the model frozen a turn
  # comes back to within 0.7 degrees: test_test_time_poses_undo_a_known_turn_with_the_model_frozen).
  assert after['rotation_deg'][0] < .5 * before['rotation_deg'][0], after['rotation_deg'][:3]
  assert np.max(after['rotation_deg'][1:]) < .7


def test_evaluation_carries_the_test_cameras_by_the_similarity_and_records_it(scene_dir, tmp_path):
  config = tiny_config(scene_dir, tmp_path / 'run', *NOISE, 'Config.max_steps = 2', 'Config.compute_lpips = False',
                       'Config.eval_test_ids = (0, 1)')
  loop.train(config)
  record = evaluate.evaluate(config)
  cameras = record['cameras']
  assert cameras['test_cameras'] == 'similarity' and not cameras['refined']
  given = cameras['errors']['given_vs_reference']
  assert record['means']['camera_rotation_deg'] == pytest.approx(given['rotation_deg_median'])
  assert 1. < given['rotation_deg_median'] < 3.  # 3 degrees of noise, less what a similarity explains.
  test_set = datasets.load_dataset('test', config)
  train_set = datasets.load_dataset('train', config)
  similarity = alignment.Similarity(cameras['similarity']['scale'], np.array(cameras['similarity']['rotation']),
                                    np.array(cameras['similarity']['shift']))
  rays = camera_evaluation.test_rays(test_set, train_set, *camera_evaluation.aligned_corrections(
      test_set, similarity))
  moved = similarity.cameras(test_set.camtoworlds)
  expected = caster.image_rays(Cameras(moved[1:2], test_set.pixtocams[1:2]),
                               dataclasses.replace(test_set.space, near=train_set.near, far=train_set.far))
  for name, got, want in zip(expected._fields, rays, expected):
    np.testing.assert_allclose(got[1], want[0], rtol=1e-5, atol=1e-5, err_msg=name)


def test_a_test_camera_lands_where_a_known_similarity_places_it(scene_dir, tmp_path):
  """The final training cameras are the reference moved by a known similarity: each test camera, in the reference's
  frame, must land where that similarity takes it, and its rays be that camera's (the similarity fitted the other
  way, final onto reference, lands it elsewhere; a test that rebuilt the rays from the similarity a run recorded
  would pass either way)."""
  test_set = datasets.load_dataset('test', tiny_config(scene_dir, tmp_path / 'run'))
  known = alignment.Similarity(1.7, corrections.so3_exp(np.array([.3, -.5, .8])), np.array([.4, -1., 2.]))
  reference = np.asarray(datasets.load_dataset('train', tiny_config(scene_dir, tmp_path / 'run')).camtoworlds,
                         np.float64)
  final = known.cameras(reference)
  cameras = camera_evaluation.TrainingCameras(final, final, reference, 4., True)
  rotations, shifts = camera_evaluation.aligned_corrections(test_set, camera_evaluation.test_similarity(cameras))
  placed = known.cameras(test_set.camtoworlds)
  np.testing.assert_allclose(corrections.corrected_cameras(test_set.camtoworlds, rotations, shifts), placed,
                             atol=1e-9)
  reverse = alignment.fit(final, reference).cameras(test_set.camtoworlds)
  assert np.abs(reverse[:, :, 3] - placed[:, :, 3]).max() > 1.
  rays = camera_evaluation.test_rays(test_set, test_set, rotations, shifts)
  expected = caster.image_rays(Cameras(placed, test_set.pixtocams), test_set.space)
  for name, got, want in zip(expected._fields, rays, expected):
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5, err_msg=name)
  assert camera_evaluation.metrics(camera_evaluation.errors(cameras))['camera_rotation_deg_unaligned'] > 30.


def test_test_time_poses_undo_a_known_turn_with_the_model_frozen(scene_dir, tmp_path):
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.n_input_views = 0', 'Config.max_steps = 300',
                       'Config.freq_reg = False', 'Config.test_pose_steps = 60', 'Config.test_pose_lr = 3e-3')
  result = loop.train(config)
  test_set = datasets.load_dataset('test', config)
  turn = corrections.so3_exp(np.array([0., 0., np.deg2rad(2.)]))
  rotations, shifts = np.repeat(turn[None], 2, 0), np.zeros((2, 3))
  rotations, _ = camera_evaluation.test_time_poses(config, result.model, result.state.params, 300,
                                                   base.subset(test_set, [0, 1]), rotations, shifts)
  left = np.rad2deg(alignment.rotation_angle(rotations))
  assert np.all(left < .7), left


def test_how_far_test_time_poses_moved_each_test_camera_is_its_turn_and_its_centre_s_shift():
  similarity = (np.repeat(corrections.so3_exp(np.array([.1, .2, -.3]))[None], 2, 0), np.array([[0., 1., 0.]] * 2))
  turn = corrections.so3_exp(np.array([0., np.deg2rad(2.), 0.]))
  after = (np.stack([turn @ similarity[0][0], similarity[0][1]]), similarity[1] + np.array([[0., 0., 0.], [.4, 0., 0.]]))
  moves = camera_evaluation.test_pose_moves(similarity, after, 4.)
  np.testing.assert_allclose(moves['per_view']['rotation_deg'], [2., 0.], atol=1e-5)  # arccos's floor
  np.testing.assert_allclose(moves['per_view']['translation'], [0., .1], atol=1e-12)
  assert moves['rotation_deg_median'] == pytest.approx(1.) and moves['translation_median'] == pytest.approx(.05)
  means = camera_evaluation.metrics({}, moves)
  assert means == {'test_pose_rotation_deg': moves['rotation_deg_median'], 'test_pose_translation': .05}


def test_camera_settings_off_leave_the_loader_rays_and_space(scene_dir, tmp_path):
  config = tiny_config(scene_dir, tmp_path / 'run')
  assert not camera_evaluation.needs_alignment(config) and not camera_evaluation.places_test_cameras(config)
  asked = dataclasses.replace(config, test_pose_steps=5)  # Exact cameras, test-time poses asked for: placed too.
  assert not camera_evaluation.needs_alignment(asked) and camera_evaluation.places_test_cameras(asked)
  data = datasets.load_dataset('train', config)
  assert data.space == RaySpace(opengl=True, near=config.near, far=config.far, height=data.height, width=data.width)
  rays = corrections.corrected_image_rays(data.rays, data.cameras, np.repeat(np.eye(3)[None], len(data.ids), 0),
                                          np.zeros((len(data.ids), 3)), data.space)
  for a, b in zip(rays, data.rays):
    np.testing.assert_array_equal(a, b)
