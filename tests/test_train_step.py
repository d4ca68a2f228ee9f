"""The jitted train step: one compile for many steps, released lr convention, non-finite guard, sharding."""

import os
import subprocess
import sys
import textwrap

import gin
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import random

from conftest import random_rays
from internal import configs
from internal.datasets.batching import Batch
from internal.losses import occlusion
from internal.losses import reconstruction
from internal.training import schedule
from internal.training import train_step as ts

TINY = ['MLP.net_depth = 2', 'MLP.net_width = 16', 'MLP.net_width_viewdirs = 8',
        'MipNerfModel.num_samples = 8', 'MLP.density_noise = 1.0']


def _setup(num_rays=8, **overrides):
  gin.parse_config(TINY)
  fields = dict(max_steps=100, lr_init=2e-3, lr_final=2e-5, lr_delay_steps=512, lr_delay_mult=0.01,
                grad_max_norm=0.1, grad_max_val=0.1, freq_reg=True, freq_reg_end=10,
                occ_reg_loss_mult=0.01, occ_wb_prior=True, white_background=False)
  fields.update(overrides)
  config = configs.Config(**fields)
  rays = random_rays(0, num_rays)
  model, state = ts.create_train_state(config, random.PRNGKey(0), rays)
  rgb = np.random.default_rng(0).uniform(size=(num_rays, 3)).astype(np.float32)
  return config, model, state, Batch(rays=rays, rgb=rgb)


def _run(config, model, state, batch, steps):
  step_fn = ts.make_train_step(config, model)
  stats = None
  for _ in range(steps):
    state, stats = step_fn(state, batch, random.PRNGKey(1))
  return step_fn, state, stats


def test_many_steps_compile_once_and_mask_follows_step():
  config, model, state, batch = _setup()
  step_fn, state, stats = _run(config, model, state, batch, 12)  # Crosses T = 10.
  assert step_fn._cache_size() == 1
  assert int(state.step) == 12
  assert float(stats['mask_visible_point']) == 1.0
  for key in ('loss', 'loss_level0', 'loss_level1', 'psnr_level0', 'psnr_level1', 'loss_occ', 'lr',
              'grad_norm_raw', 'grad_norm', 'grad_norm_clipped', 'grad_abs_max', 'grads_finite'):
    assert np.isfinite(float(stats[key])), key


def test_first_update_uses_lr_of_step_one():
  # Adam's first step moves every parameter with |g| >> eps by exactly lr.
  config, model, state, batch = _setup(max_steps=43945)
  before = jax.tree.map(np.asarray, state.params)
  _, after, stats = _run(config, model, state, batch, 1)
  moved = max(float(np.max(np.abs(np.asarray(a) - b)))
              for a, b in zip(jax.tree.leaves(after.params), jax.tree.leaves(before)))
  lr1 = float(schedule.learning_rate(1, 2e-3, 2e-5, 43945, 512, 0.01))
  assert float(stats['lr']) == pytest.approx(lr1, rel=1e-6)
  assert moved == pytest.approx(lr1, rel=1e-3)


def test_clipping_bounds_the_update_gradient():
  config, model, state, batch = _setup()
  _, _, stats = _run(config, model, state, batch, 1)
  assert float(stats['grad_abs_max']) <= 0.1 + 1e-7
  assert float(stats['grad_norm_clipped']) <= 0.1 + 1e-6


UPDATE = 'new parameters / optimizer state'


def _nan_gradients(data_loss):
  """data_loss plus 0 * sqrt(|x - x|): the same finite loss, NaN gradients (0 * inf)."""
  return lambda rgb, *args: data_loss(rgb, *args) + 0. * jnp.sum(jnp.sqrt(jnp.abs(rgb - jax.lax.stop_gradient(rgb))))


LR = 'learning rate (Config.lr_init, lr_final, lr_delay_mult)'
COLOURS = 'targets of the batch (colours of the images, depth priors)'


@pytest.mark.parametrize('cause, reason', [
    ('data', f'{COLOURS}, then loss, gradients, {UPDATE}'),
    ('rays', f'rays of the batch (the training cameras), then loss, gradients, {UPDATE}'),
    ('gradients', f'gradients, then {UPDATE}'), ('nan_lr', f'{LR}, then {UPDATE}'), ('negative_lr', LR)])
def test_guard_skips_the_update_and_names_the_first_cause(cause, reason, monkeypatch):
  config, model, state, batch = _setup()
  if cause == 'data':
    batch.rgb[0, 0] = np.nan
  elif cause == 'rays':
    origins = np.array(batch.rays.origins)
    origins[0, 0] = np.nan
    batch = batch._replace(rays=batch.rays._replace(origins=origins))
  elif cause == 'gradients':
    monkeypatch.setattr(reconstruction, 'data_loss', _nan_gradients(reconstruction.data_loss))
  else:
    lr = {'nan_lr': np.nan, 'negative_lr': -1e-3}[cause]
    monkeypatch.setattr(schedule, 'config_learning_rate', lambda config, step: jnp.float32(lr))
  before = jax.tree.map(np.asarray, state)
  _, after, stats = _run(config, model, state, batch, 2)
  assert int(after.step) == 2 and bool(stats['skipped'])
  assert ts.skip_reason(jax.device_get(stats)) == reason
  for a, b in zip(jax.tree.leaves((after.params, after.opt_state)), jax.tree.leaves((before.params, before.opt_state))):
    np.testing.assert_array_equal(np.asarray(a), b)


@pytest.mark.parametrize('term, value, reason', [
    ('loss_occ', 10., 'loss_occ x its weight Config.occ_reg_loss_mult, then loss'),
    ('loss_occ', np.inf, 'loss_occ, then loss'),
    ('loss_level0', 10., f'loss_level0 x its weight Config.coarse_loss_mult, then loss')])
def test_guard_names_the_loss_term_and_the_weight_that_made_it_overflow(term, value, reason, monkeypatch):
  # A finite term times a finite weight can pass float32's range: the message names the weight.
  config, model, state, batch = _setup(occ_reg_loss_mult=1e38, coarse_loss_mult=1e38)
  if term == 'loss_occ':
    monkeypatch.setattr(occlusion, 'occlusion_loss', lambda *args: jnp.float32(value))
  else:
    monkeypatch.setattr(reconstruction, 'data_loss', lambda rgb, *args: jnp.float32(value) + 0. * jnp.sum(rgb))
  _, after, stats = _run(config, model, state, batch, 1)
  assert bool(stats['skipped']) and ts.skip_reason(jax.device_get(stats)) == reason


def test_each_loss_term_of_compute_loss_is_named_in_its_order():
  config, model, state, batch = _setup(distortion_loss_mult=.01)
  stats = jax.device_get(_run(config, model, state, batch, 1)[2])
  assert ts.loss_terms(stats) == [('loss_level0', 'coarse_loss_mult'), ('loss_level1', ''),
                                  ('weight_l2', 'weight_decay_mult'), ('loss_occ', 'occ_reg_loss_mult'),
                                  ('loss_distortion', 'distortion_loss_mult')]
  assert {f'{key}_weighted_finite' for key, weight in ts.loss_terms(stats) if weight} <= set(stats)


def test_skip_counter_counts_and_stops_after_max_consecutive_skips():
  stats = lambda skipped: {'skipped': skipped, 'loss_finite': True, 'grads_finite': True, 'lr_valid': not skipped,
                           'update_finite': True}
  counter = ts.SkipCounter('skip', 3)
  for step, skipped in enumerate([1, 1, 0, 1, 1, 0, 1], start=1):
    counter.record(stats(skipped), step)
  assert (counter.total, counter.streak) == (5, 1)
  counter.record(stats(1), 8)
  with pytest.raises(ts.NonFiniteError, match=r'^steps 7-9: 3 consecutive updates skipped \(last: non-finite '
                     r'learning rate \(Config.lr_init, lr_final, lr_delay_mult\)\), Config.max_skipped_steps = 3;'):
    counter.record(stats(1), 9)
  raising = ts.SkipCounter('raise', 100)
  raising.record(stats(0), 1)
  with pytest.raises(ts.NonFiniteError, match=r"^step 2: non-finite learning rate .*nonfinite_grad_policy = 'skip'"):
    raising.record(stats(1), 2)
  assert issubclass(ts.NonFiniteError, FloatingPointError)


@pytest.mark.parametrize('overrides', [
    dict(freq_reg_end=0), dict(freq_reg_end=1), dict(freq_reg=False, occ_reg_loss_mult=0.),
    dict(occ_reg_range=0, occ_wb_prior=False), dict(occ_reg_range=1000),
    dict(max_vis_freq_ratio=0.2), dict(freq_mask_layout='paper'), dict(distortion_loss_mult=0.01)])
def test_extreme_settings_train_finitely(overrides):
  config, model, state, batch = _setup(**overrides)
  _, state, stats = _run(config, model, state, batch, 2)
  assert np.isfinite(float(stats['loss']))
  assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(state.params))


def test_batch_of_one_ray_and_zero_length_viewdir():
  config, model, state, batch = _setup(num_rays=1)
  batch = batch._replace(rays=batch.rays._replace(viewdirs=np.zeros((1, 3), np.float32)))
  _, state, stats = _run(config, model, state, batch, 2)
  assert bool(stats['grads_finite']) and np.isfinite(float(stats['loss']))


SHARDED = textwrap.dedent('''
    import os, sys
    sys.path.insert(0, os.getcwd()); sys.path.insert(0, os.path.join(os.getcwd(), 'tests'))
    import jax, numpy as np
    from jax import random
    import test_train_step as t
    from internal.run import sharding
    assert len(jax.devices()) == 2
    results = []
    for mesh in (None, sharding.data_mesh()):
      config, model, state, batch = t._setup(num_rays=16)
      if mesh is not None:
        state, batch = sharding.replicate(state, mesh), sharding.shard_batch(batch, mesh)
      _, state, stats = t._run(config, model, state, batch, 3)
      results.append((float(stats['loss']), jax.tree.map(np.asarray, state.params)))
    (loss1, p1), (loss2, p2) = results
    assert abs(loss1 - loss2) < 1e-5, (loss1, loss2)
    diff = max(float(np.max(np.abs(a - b))) for a, b in zip(jax.tree.leaves(p1), jax.tree.leaves(p2)))
    assert diff < 1e-5, diff
    print('OK', loss1, loss2, diff)
''')


def test_two_device_mesh_matches_one_device():
  root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  env = dict(os.environ, XLA_FLAGS='--xla_force_host_platform_device_count=2', JAX_PLATFORMS='cpu')
  result = subprocess.run([sys.executable, '-c', SHARDED], cwd=root, env=env, capture_output=True,
                          text=True, timeout=600)
  assert result.returncode == 0, result.stdout + result.stderr
  assert 'OK' in result.stdout
