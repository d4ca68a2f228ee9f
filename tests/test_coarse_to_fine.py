"""Tests of internal/models/coarse_to_fine.py (BARF's coarse-to-fine weights) against hand computations, its extremes,
and how the weights reach the models' encodings (freq_schedule.model_masks)."""

import dataclasses

import jax
import numpy as np
import pytest

from internal import config_loader
from internal.configs import Config
from internal.models import coarse_to_fine, encoding, freq_schedule, mip_nerf, nerf


def test_band_weights_by_hand():
  # 4 bands opening between 0 and 0.5 of 100 steps: alpha = 4 * (step / 100) / 0.5.
  weights = coarse_to_fine.band_weights(4, 30, 100, 0., .5)  # alpha = 2.4: bands 0, 1 open, band 2 at 0.4.
  np.testing.assert_allclose(weights, [1., 1., (1. - np.cos(.4 * np.pi)) / 2., 0.], atol=1e-6)  # float32.
  assert abs(float(weights[2]) - 0.3454915) < 1e-6
  weights = coarse_to_fine.band_weights(4, 40, 100, .1, .5)  # alpha = 4 * 0.3 / 0.4 = 3: bands 0-2 open.
  np.testing.assert_allclose(weights, [1., 1., 1., 0.], atol=1e-6)


def test_band_weights_extremes_are_exact():
  closed = coarse_to_fine.band_weights(16, 5, 1000, .1, .5)  # Before start: every band exactly 0.
  assert closed.dtype == np.float32 and np.all(np.asarray(closed) == 0.)
  for step in (500, 501, 1000):  # From end on: every band exactly 1 (the encoding as without the weights).
    assert np.all(np.asarray(coarse_to_fine.band_weights(16, step, 1000, .1, .5)) == 1.)


def test_band_weights_rise_monotonically_under_jit():
  steps = np.arange(0, 1001, 10)
  weights = np.asarray(jax.vmap(jax.jit(lambda s: coarse_to_fine.band_weights(8, s, 1000, .1, .5)))(steps))
  assert np.all(np.diff(weights, axis=0) >= 0.) and np.all(np.diff(weights, axis=1) <= 0.)  # In step; in band.


@pytest.mark.parametrize('interleaved', [False, True])
def test_feature_weights_follow_the_encodings_order(interleaved):
  weights = np.asarray(coarse_to_fine.feature_weights(3, 30, 100, 0., .5, interleaved))  # alpha = 1.8.
  kind, degree, _ = encoding.feature_layout(3, interleaved=interleaved)
  assert weights.shape == (encoding.width(3),)
  assert np.all(weights[kind == 0] == 1.)  # The raw coordinates always.
  band = (1. - np.cos(.8 * np.pi)) / 2.
  np.testing.assert_allclose(weights[kind > 0], np.array([1., band, 0.])[degree[kind > 0]], atol=1e-7)


def test_off_by_default_leaves_the_masks_unchanged():
  config = Config(freq_reg=True, freq_reg_end=100, max_steps=200)
  assert coarse_to_fine.weights_at(config, (16, 4), 50) == (None, None)
  for model in (mip_nerf.MipNerfModel(), nerf.NerfModel()):
    masks = freq_schedule.model_masks(config, model, 50)
    expected = freq_schedule.masks_at(config, model.encoding_degrees(), 50, model.interleaved_encoding)
    for got, want in zip(masks, expected):
      assert np.array_equal(np.asarray(got), np.asarray(want))
  assert freq_schedule.model_masks(Config(), mip_nerf.MipNerfModel(), 50) == (None, None)


@pytest.mark.parametrize('model', [mip_nerf.MipNerfModel(), nerf.NerfModel()], ids=['mipnerf', 'nerf'])
def test_weights_reach_the_models_masks(model):
  config = Config(coarse_to_fine=True, max_steps=100)
  point, view = freq_schedule.model_masks(config, model, 30)
  num_point, num_view = model.encoding_degrees()
  np.testing.assert_array_equal(point, coarse_to_fine.feature_weights(num_point, 30, 100, .1, .5,
                                                                      model.interleaved_encoding))
  np.testing.assert_array_equal(view, coarse_to_fine.feature_weights(num_view, 30, 100, .1, .5,
                                                                     model.interleaved_encoding))
  # With FreeNeRF's mask as well: the product of the two.
  both = dataclasses.replace(config, freq_reg=True, freq_reg_end=50)
  mask_point, _ = freq_schedule.masks_at(both, model.encoding_degrees(), 30, model.interleaved_encoding)
  np.testing.assert_array_equal(freq_schedule.model_masks(both, model, 30)[0], mask_point * point)


@pytest.mark.parametrize('start,end', [(.5, .5), (.6, .5), (-.1, .5)])
def test_bad_schedule_is_one_clear_error(start, end):
  config = Config(coarse_to_fine=True, coarse_to_fine_start=start, coarse_to_fine_end=end)
  with pytest.raises(ValueError, match=r'Config\.coarse_to_fine_start = .* and Config\.coarse_to_fine_end = '):
    coarse_to_fine.check_settings(config)


def test_the_loader_checks_the_schedule():
  with pytest.raises(ValueError, match=r'Config\.coarse_to_fine_start = 0\.6'):
    config_loader.validate(Config(coarse_to_fine=True, coarse_to_fine_start=.6))
  with pytest.warns(UserWarning, match=r'Config\.coarse_to_fine_end = 1\.5 exceeds 1'):
    coarse_to_fine.check_settings(Config(coarse_to_fine=True, coarse_to_fine_end=1.5))
  config_loader.validate(Config(coarse_to_fine_start=.6, coarse_to_fine_end=2e-38))  # Off: read by nothing.
