"""Depth priors in training: the batch sampler's patches of real views and rays through SfM points, the loss terms
(present only when their weight is positive), NDC disparity, and short runs that train and evaluate with them."""

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import random

from internal import config_loader
from internal.cameras import caster, corrections
from internal.cameras.records import Cameras
from internal.datasets import batching, load_dataset, sfm_depth
from internal.evaluation import evaluate
from internal.losses import depth_pearson
from internal.pipeline import loop
from internal.training import camera_refinement
from internal.training import train_step
from test_checkpoints import tiny_config
from test_depth_prior import _capture_with_points
from tools import synthetic_depth

FORWARD = ["Config.generated_rig = 'forward'", 'Config.generated_size = (24, 32)', 'Config.n_input_views = 2',
           'Config.near = 0.', 'Config.far = 1.', 'Config.white_background = False', 'Config.freq_reg_end = 2']


def test_patch_indices_are_squares_inside_one_image():
  rng = np.random.default_rng(0)
  image, pixel = batching.patch_indices(rng, 3, 10, 12, 50, 4)
  assert image.shape == (50,) and pixel.shape == (50, 16) and set(image) <= {0, 1, 2}
  for flat in pixel:
    rows, cols = np.divmod(flat, 12)
    top, left = rows.min(), cols.min()
    assert top + 4 <= 10 and left + 4 <= 12
    assert sorted(zip(rows, cols)) == [(top + i, left + j) for i in range(4) for j in range(4)]


@pytest.fixture(name='forward_priors', scope='module')
def fixture_forward_priors(tmp_path_factory):
  """(config with a ranking prior, training Dataset) of the tiny generated forward scene, its maps written."""
  root = tmp_path_factory.mktemp('forward')
  config = tiny_config(root / 'scene', root / 'run', *FORWARD)
  data = load_dataset('train', config, ground_truth=True)
  os.makedirs(root / 'priors')
  rng = np.random.default_rng(0)
  for path, depth in zip(data.image_paths, data.depths):
    np.save(root / 'priors' / (os.path.basename(path)[:-4] + '.npy'), synthetic_depth.monocular_like(
        depth, rng, .8, 1., .02))
  config = tiny_config(root / 'scene', root / 'run', *FORWARD, f"Config.depth_prior_dir = '{root / 'priors'}'",
                       "Config.depth_prior_kind = 'disparity'", 'Config.depth_rank_loss_mult = 1.',
                       'Config.depth_prior_rays = 128', 'Config.max_steps = 3', 'Config.curve_every = 0')
  return config, data


def _find_patch(data, maps, rays, prior, size):
  """(image, top, left) of the training-view patch whose rays [n, ...] and prior [n] these are, or None."""
  for image in range(len(data.ids)):
    for top in range(data.height - size + 1):
      for left in range(data.width - size + 1):
        window = (image, slice(top, top + size), slice(left, left + size))
        if np.array_equal(data.rays.directions[window].reshape(-1, 3), rays.directions) and np.array_equal(
            maps[window].reshape(-1), prior):
          return image, top, left
  return None


def test_prior_patches_are_real_training_pixels_with_their_maps_and_depend_only_on_the_step(forward_priors):
  config, data = forward_priors
  maps = batching.depth_prior.load_maps(data, config)
  batcher = batching.make_batcher(data, config)
  batch = batcher(5)
  size = config.depth_patch_size
  assert batch.prior_rays.origins.shape == (128 // size**2, size**2, 3) and batch.prior.shape == (2, 64)
  for p in range(2):
    patch = jax.tree.map(lambda x, p=p: x[p], batch.prior_rays)
    assert _find_patch(data, maps, patch, batch.prior[p], size) is not None
    assert patch.origins.dtype == np.float32
  again = batcher(5)
  np.testing.assert_array_equal(again.prior, batch.prior)
  assert not np.array_equal(batcher(6).prior, batch.prior)
  assert batching.make_batcher(data, dataclasses.replace(config, depth_rank_loss_mult=0.))(5).prior_rays is None


@pytest.mark.slow
def test_the_prior_terms_enter_the_loss_only_when_their_weight_is_positive(forward_priors):
  config, data = forward_priors
  batch = batching.make_batcher(data, config)(1)
  model, state = train_step.create_train_state(config, random.PRNGKey(0), batch.rays)
  key = random.PRNGKey(1)
  off = dataclasses.replace(config, depth_rank_loss_mult=0.)
  base, stats = train_step.compute_loss(off, model, state.params, batch, key, 1)
  assert not {'loss_depth_rank', 'loss_depth_pearson', 'loss_sfm_depth'} & set(stats)
  both = dataclasses.replace(config, depth_rank_loss_mult=2., depth_pearson_loss_mult=.5)
  loss, stats = train_step.compute_loss(both, model, state.params, batch, key, 1)
  assert float(stats['loss_depth_rank']) > 0 and 0 < float(stats['loss_depth_pearson']) <= 2.2
  assert float(loss) == pytest.approx(float(base) + 2. * float(stats['loss_depth_rank'])
                                      + .5 * float(stats['loss_depth_pearson']), rel=1e-5)
  grads = [jax.grad(lambda p, c=c: train_step.compute_loss(c, model, p, batch, key, 1)[0])(state.params)
           for c in (off, both)]
  difference = jax.tree.map(lambda a, b: float(np.abs(a - b).max()), *grads)
  assert max(jax.tree.leaves(difference)) > 0


def test_a_depth_prior_trains_with_refinement_its_patches_from_the_corrected_cameras(forward_priors):
  """Refinement corrects every family of training-view rays once, before the terms: the prior's patches too (NDC
  rays of the forward rig) are the rays of the corrected cameras; the step trains, and the cameras move."""
  config, data = forward_priors
  config = dataclasses.replace(config, optimize_cameras=True, camera_lr_init=1e-2, camera_lr_final=1e-3)
  config_loader.validate(config)  # No refusal of a depth prior with refinement.
  batch = batching.make_batcher(data, config)(1)
  assert batch.prior_pixels.view.shape == batch.prior.shape
  cameras = camera_refinement.init(config, data)
  free = np.zeros((len(data.ids), 6), np.float32)
  free[0], free[1] = [.02, -.01, .03, .01, .02, -.01], [-.02, .01, -.03, -.01, -.02, .01]
  corrected = camera_refinement.corrected_batch(cameras, jnp.asarray(free), batch)
  rotations, shifts = (np.asarray(x, np.float64) for x in camera_refinement.view_corrections(free, cameras.centres))
  moved = corrections.corrected_cameras(data.camtoworlds, rotations, shifts)
  expected = caster.cast(Cameras(moved, data.pixtocams), batch.prior_pixels, data.space)
  for field in ('origins', 'directions', 'viewdirs', 'radii'):
    np.testing.assert_allclose(getattr(corrected.prior_rays, field), getattr(expected, field), rtol=1e-4, atol=1e-5,
                               err_msg=field)
  assert not np.allclose(corrected.prior_rays.origins, batch.prior_rays.origins, atol=1e-3)
  model, state = train_step.create_train_state(config, random.PRNGKey(0), batch.rays, cameras)
  new, stats = train_step.make_train_step(config, model)(state, batch, random.PRNGKey(1))
  assert np.isfinite(float(stats['loss_depth_rank'])) and not bool(stats['skipped'])
  assert np.abs(np.asarray(camera_refinement.gauge_fixed(new.cameras.free, new.cameras.centres))).max() > 0


def test_ndc_disparity_is_one_minus_t():
  """On an NDC ray, 1 - t is the near plane's distance over the world depth: affine in disparity (Pearson)."""
  origins, directions = np.zeros((5, 3)), np.array([[.1 * i, -.05 * i, -1.] for i in range(5)])
  ndc_o, ndc_d = caster.convert_to_ndc(origins, directions, 30., 24, 32)
  depths = np.array([1.5, 2., 4., 9., 40.])
  points = origins + depths[:, None] * directions  # World z = -depth.
  z_ndc = 1. + 2. / points[:, 2]
  t = (z_ndc - ndc_o[:, 2]) / ndc_d[:, 2]
  np.testing.assert_allclose(depth_pearson.pearson_values(t, 'disparity', True), 1. / depths, rtol=1e-9)
  np.testing.assert_allclose(depth_pearson.pearson_values(t, 'depth', True), depths, rtol=1e-9)
  np.testing.assert_allclose(depth_pearson.pearson_values(depths, 'disparity', False), 1. / depths)


@pytest.mark.slow
def test_a_run_with_a_ranking_prior_trains_and_evaluates(forward_priors):
  config, _ = forward_priors
  result = loop.train(config)
  assert int(result.state.step) == 3 and result.skipped == 0
  record = evaluate.evaluate(dataclasses.replace(config, compute_lpips=False))
  assert np.isfinite(record['means']['depth_mae'])


def test_a_capture_trains_with_its_sfm_prior_and_reports_depth_at_its_points(tmp_path):
  _, _, capture = _capture_with_points(tmp_path, tmp_path / 'scene')
  config = tiny_config(capture, tmp_path / 'run', "Config.dataset_loader = 'capture'", 'Config.n_input_views = 4',
                       'Config.llffhold = 4', 'Config.white_background = False', 'Config.sfm_depth_loss_mult = 1.',
                       'Config.depth_prior_rays = 64', 'Config.max_steps = 3', 'Config.curve_every = 0',
                       'Config.near = 0.1', 'Config.compute_lpips = False', 'Config.freq_reg_end = 2')
  data = load_dataset('train', config)
  batch = batching.make_batcher(data, config)(2)
  depth, weight = sfm_depth.training_prior(data, config)
  assert batch.sfm_rays.origins.shape == (64, 3) and np.all(batch.sfm_weight > 0)
  for k in range(64):  # Each ray is a training pixel with a point, carrying that pixel's depth and weight.
    match = np.nonzero(np.all(data.rays.directions == batch.sfm_rays.directions[k], axis=-1) & (weight > 0))
    assert len(match[0]) == 1 and depth[match][0] == batch.sfm_depth[k] and weight[match][0] == (
        batch.sfm_weight[k])
  result = loop.train(config)
  assert int(result.state.step) == 3 and result.skipped == 0
  record = evaluate.evaluate(config)
  assert 0 < record['means']['sfm_depth_mae'] < np.inf
