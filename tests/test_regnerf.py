"""RegNeRF's terms against hand computations: depth TV, its weight schedule, near/far annealing, poses, patches."""

import dataclasses

import gin
import jax
import numpy as np
import pytest
from jax import random

from conftest import random_rays
from internal import configs
from internal.losses import depth_smoothness
from internal.training import anneal, train_step
from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import random_poses
from internal.datasets.batching import Batch
from internal.rays import Rays


def test_tv_norm_of_a_known_depth_patch():
  depth = np.array([[[1., 2., 4.], [1., 3., 4.], [0., 0., 0.]]])  # One 3x3 patch.
  # (d00-d01)^2 + (d00-d10)^2 on the top-left 2x2: (1+0), (4+1), (4+1), (1+9).
  assert float(depth_smoothness.tv_norm(depth, np.ones((1, 2, 2)))) == pytest.approx((1 + 5 + 5 + 10) / 4)
  weighting = np.array([[[1., 0.], [0.5, 0.]]])
  assert float(depth_smoothness.tv_norm(depth, weighting)) == pytest.approx((1 + 0.5 * 5) / 4)


def test_tv_weighting_released_zero_mask_weight_zeroes_the_loss_and_the_fix_unweights_it():
  acc = np.full((2, 4, 4), 0.5, np.float32)
  assert np.all(np.asarray(depth_smoothness.tv_weighting(acc, 0., fix=False)) == 0.)
  assert np.all(np.asarray(depth_smoothness.tv_weighting(acc, 0., fix=True)) == 1.)
  assert np.asarray(depth_smoothness.tv_weighting(acc, 1., fix=True)).shape == (2, 3, 3)
  assert np.all(np.asarray(depth_smoothness.tv_weighting(acc, 2., fix=False)) == 1.)


@pytest.mark.parametrize('step,expected', [(0, 400.), (256, 200.05), (512, 0.1), (1000, 0.1)])
def test_tv_weight_schedule_of_the_released_configs(step, expected):
  assert float(depth_smoothness.linear(step, 512, 400., 0.1)) == pytest.approx(expected)


def test_expected_depth_clamps_the_opacity_and_clips_to_the_ray():
  t_vals = np.array([[1., 2., 3.], [1., 2., 3.]])
  weights = np.array([[0.25, 0.25], [0., 0.]])
  # (0.25 * 1.5 + 0.25 * 2.5) / 0.5 = 2; an empty ray gives 0, clipped to the near end.
  np.testing.assert_allclose(depth_smoothness.expected_depth(weights, t_vals), [2., 1.])


def test_tv_weight_decays_only_when_asked():
  config = configs.Config(depth_tvnorm_decay=True, depth_tvnorm_maxstep=512, depth_tvnorm_loss_mult_start=400.,
                          depth_tvnorm_loss_mult_end=0.1, depth_tvnorm_loss_mult=0.1)
  assert float(depth_smoothness.tv_weight(config, 256)) == pytest.approx(200.05)
  assert depth_smoothness.tv_weight(configs.Config(depth_tvnorm_loss_mult=0.3), 256) == 0.3


@pytest.mark.parametrize('step,expected', [(0, (1.25, 2.75)), (128, (0.875, 3.125)), (256, (0.5, 3.5)),
                                           (1000, (0.5, 3.5))])
def test_annealed_near_far_of_the_dtu_configs(step, expected):
  assert [float(v) for v in anneal.near_far(step, 0.5, 3.5, 256, 0.5, 0.5)] == pytest.approx(expected)


@pytest.mark.parametrize('step,expected', [(0, (0.9999, 1.)), (256, (0.49995, 1.)), (512, (0., 1.))])
def test_annealed_near_far_of_the_llff_configs(step, expected):
  assert [float(v) for v in anneal.near_far(step, 0., 1., 512, 1e-4, 1.)] == pytest.approx(expected)


def _ring_poses(n=8, opengl=False):
  """[n,3,4] cameras on a ring at height 1 looking at the origin (OpenCV +z forward, or OpenGL)."""
  out = []
  for theta in np.linspace(0, 2 * np.pi, n, endpoint=False):
    position = np.array([np.cos(theta), np.sin(theta), 1.])
    out.append(algebra.viewmatrix(position if opengl else -position, np.array([0., 0., 1.]), position))
  return np.stack(out)


def test_dtu_random_poses_count_box_and_focus():
  poses = _ring_poses()
  out = random_poses.dtu_random_poses(poses, 50, np.random.default_rng(0), 1., jitter=False)
  assert out.shape == (50, 3, 4)
  focus = algebra.focus_point(poses)
  to_focus = algebra.normalize(focus - out[:, :, 3])
  np.testing.assert_allclose(out[:, :, 2], to_focus, atol=1e-6)  # +z looks at the focus point.
  np.testing.assert_allclose(np.einsum('nij,nik->njk', out[:, :, :3], out[:, :, :3]),
                             np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-6)


def test_llff_random_poses_released_keeps_one_pose_and_the_fix_keeps_all():
  poses, bounds = _ring_poses(opengl=True), np.array([[1., 10.]])
  assert random_poses.llff_random_poses(poses, bounds, 100, np.random.default_rng(0), True).shape == (1, 3, 4)
  every = random_poses.llff_random_poses(poses, bounds, 100, np.random.default_rng(0), False)
  last = random_poses.llff_random_poses(poses, bounds, 100, np.random.default_rng(0), True)
  assert every.shape == (100, 3, 4)
  np.testing.assert_allclose(every[-1], last[0])  # The released bug keeps the last draw.


def _full_and_patch(c2w, pixtocam, space, x0: int, y0: int):
  """(the image's rays [H,W,...], the rays of the 8 x 8 patch from column x0, row y0 [8,8,...]) of one camera."""
  cameras = Cameras(c2w[None], pixtocam[None])
  full = Rays(*[x[0] for x in caster.image_rays(cameras, space)])
  patch = caster.cast(cameras, random_poses.patch_pixels([0], [x0], [y0], 8), random_poses.patch_space(space))
  return full, Rays(*[x[0] for x in patch])


def test_dtu_patch_rays_are_the_full_image_rays_at_those_pixels():
  c2w, pixtocam = _ring_poses()[1], np.linalg.inv(np.array([[30., 0., 20.], [0., 30., 15.], [0., 0., 1.]]))
  space = RaySpace(opengl=False, near=.5, far=3.5, height=30, width=40, plane_z=0.)
  full, patch = _full_and_patch(c2w, pixtocam, space, 7, 5)
  for name, a, b in zip(full._fields, patch, full):
    np.testing.assert_allclose(a, b[5:13, 7:15], rtol=1e-5, atol=1e-6, err_msg=name)


def test_llff_patch_rays_are_the_full_image_ndc_rays_with_unit_viewdirs():
  c2w, focal = _ring_poses(opengl=True)[0], 25.
  space = RaySpace(opengl=True, near=0., far=1., height=30, width=40, ndc_focal=focal)
  full, patch = _full_and_patch(c2w, algebra.focal_pixtocam(focal, 30, 40), space, 3, 9)
  for name in ('origins', 'directions', 'radii', 'near', 'far'):
    np.testing.assert_allclose(getattr(patch, name), getattr(full, name)[9:17, 3:11], rtol=1e-5, atol=1e-6)
  viewdirs = full.viewdirs[9:17, 3:11]
  np.testing.assert_allclose(patch.viewdirs, viewdirs / np.linalg.norm(viewdirs, axis=-1, keepdims=True),
                             rtol=1e-5)


def test_a_patch_on_the_last_column_takes_the_next_pixels_radius_and_the_image_the_released_one():
  c2w, focal = _ring_poses(opengl=True)[0], 25.
  space = RaySpace(opengl=True, near=0., far=1., height=30, width=40, ndc_focal=focal)
  full, patch = _full_and_patch(c2w, algebra.focal_pixtocam(focal, 30, 40), space, 32, 22)
  np.testing.assert_allclose(patch.radii[:-1, :-1], full.radii[22:29, 32:39], rtol=1e-5)
  assert not np.allclose(patch.radii[:, -1], full.radii[22:30, 39], rtol=1e-5, atol=0.)


def test_train_step_adds_the_depth_tv_only_when_asked():
  gin.parse_config(['MLP.net_depth = 2', 'MLP.net_width = 32', 'MipNerfModel.num_samples = 16'])
  rays = random_rays(0, 64)
  patch = jax.tree.map(lambda x: x.reshape((4, 4, 4, -1)), random_rays(1, 64))
  batch = Batch(rays=rays, rgb=np.full((64, 3), 0.5, np.float32))
  base = configs.Config(max_steps=10, depth_tvnorm_loss_mult=0.)
  tv = configs.Config(max_steps=10, patch_size=4, batch_size_random=64, depth_tvnorm_loss_mult=0.5,
                      anneal_nearfar=True, anneal_nearfar_steps=4, anneal_nearfar_perc=0.5)
  model, state = train_step.create_train_state(base, random.PRNGKey(0), rays)
  key = random.PRNGKey(1)
  loss0, stats0 = train_step.compute_loss(base, model, state.params, batch, key, 1)
  loss1, stats1 = train_step.compute_loss(tv, model, state.params, batch._replace(patch_rays=patch), key, 1)
  assert 'loss_depth_tv' not in stats0
  # The TV term is 0.1 x coarse TV + 0.5 x fine TV, with released mask weight 0: zero, so the losses differ
  # only through the annealed near/far of the data rays.
  assert float(stats1['loss_depth_tv']) == 0.
  fixed = dataclasses.replace(tv, regnerf_fix_released_bugs=True)
  _, stats2 = train_step.compute_loss(fixed, model, state.params, batch._replace(patch_rays=patch), key, 1)
  expected = 0.1 * stats2['depth_tv_level0'] + 0.5 * stats2['depth_tv_level1']
  assert float(stats2['loss_depth_tv']) == pytest.approx(float(expected)) and float(expected) > 0
  assert float(loss0) != float(loss1)


def test_annealing_narrows_each_rays_own_bounds():
  rays = random_rays(0, 6)
  near, far = np.linspace(.3, .8, 6)[:, None], np.linspace(3., 4., 6)[:, None]  # A capture's bounds, not Config's.
  rays = rays._replace(near=near.astype(np.float32), far=far.astype(np.float32))
  config = configs.Config(anneal_nearfar=True, anneal_nearfar_steps=10, anneal_nearfar_perc=.5, anneal_mid_perc=.5)
  start, end = anneal.anneal_rays(config, rays, 0), anneal.anneal_rays(config, rays, 10)
  mid = (near + far) / 2
  np.testing.assert_allclose(start.near, mid + .5 * (near - mid), rtol=1e-6)
  np.testing.assert_allclose(start.far, mid + .5 * (far - mid), rtol=1e-6)
  np.testing.assert_allclose(end.near, near, rtol=1e-6)
  np.testing.assert_allclose(end.far, far, rtol=1e-6)
