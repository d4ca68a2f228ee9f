"""Data loss normalization, PSNR bookkeeping, occlusion and distortion losses against hand computations."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from internal.losses import reconstruction
from internal.losses import occlusion


def test_data_loss_is_three_times_channel_mse_and_true_psnr_is_not():
  rng = np.random.default_rng(0)
  rgb, target = rng.uniform(size=(2, 64, 3))
  lossmult = np.ones((64, 1))
  mse = np.mean((rgb - target)**2)
  assert float(reconstruction.data_loss(rgb, target, lossmult)) == pytest.approx(3 * mse, rel=1e-5)
  assert float(reconstruction.true_psnr(rgb, target, lossmult)) == pytest.approx(-10 * np.log10(mse), rel=1e-5)


def test_mse_to_psnr_is_float64_for_numbers_and_jax_for_jax_arrays():
  psnr = reconstruction.mse_to_psnr(1e-3 + 1e-12)  # float32 could not hold the 1e-12.
  assert psnr.dtype == np.float64 and psnr == -10 * np.log10(1e-3 + 1e-12)
  assert reconstruction.mse_to_psnr(0.) == np.inf and reconstruction.mse_to_psnr(.01) == 20.
  traced = jax.jit(reconstruction.mse_to_psnr)(jnp.float32(.01))
  assert isinstance(traced, jax.Array) and float(traced) == pytest.approx(20., rel=1e-6)


def test_data_loss_respects_lossmult():
  rgb = np.zeros((2, 3))
  target = np.array([[1., 1., 1.], [0., 0., 0.]])
  assert float(reconstruction.data_loss(rgb, target, np.array([[1.], [0.]]))) == pytest.approx(3.)
  assert float(reconstruction.data_loss(rgb, target, np.array([[0.], [1.]]))) == pytest.approx(0.)


def _occ_inputs():
  density = np.arange(2 * 8, dtype=np.float32).reshape(2, 8)
  rgb = np.full((2, 8, 3), 0.5, np.float32)
  rgb[0, 5] = 1.0   # White sample inside wb_range.
  rgb[1, 6] = 0.0   # Black sample outside wb_range.
  rgb[1, 2] = 0.995  # White (mean > 0.99).
  return density, rgb


def test_occlusion_loss_first_m_samples_mean_over_all_entries():
  density, rgb = _occ_inputs()
  expected = (density[:, :3].sum()) / density.size
  assert float(occlusion.occlusion_loss(density, rgb, 3, False, 0)) == pytest.approx(expected)


def test_occlusion_loss_black_white_prior_uses_predicted_sample_colours():
  density, rgb = _occ_inputs()
  # M = 2 plus black/white samples among the first wb_range = 6: [0, 5] and [1, 2]; [1, 6] is outside.
  expected = (density[:, :2].sum() + density[0, 5] + density[1, 2]) / density.size
  assert float(occlusion.occlusion_loss(density, rgb, 2, True, 6)) == pytest.approx(expected)


def test_occlusion_extremes_m_zero_and_m_beyond_samples():
  density, rgb = _occ_inputs()
  assert float(occlusion.occlusion_loss(density, rgb, 0, False, 15)) == 0.
  assert float(occlusion.occlusion_loss(density, rgb, 1000, False, 15)) == pytest.approx(density.mean())


def test_occlusion_gradient_flows_to_density_only():
  density, rgb = _occ_inputs()
  g_density, g_rgb = jax.grad(occlusion.occlusion_loss, argnums=(0, 1))(density, rgb, 3, True, 15)
  assert np.all(np.asarray(g_rgb) == 0)
  np.testing.assert_allclose(np.asarray(g_density)[:, :3], 1. / density.size)
  np.testing.assert_allclose(np.asarray(g_density)[:, 3:][rgb.mean(-1)[:, 3:] == 0.5], 0.)


def test_distortion_loss_brute_force():
  rng = np.random.default_rng(1)
  s = np.sort(rng.uniform(size=(3, 6)), axis=-1)
  w = rng.uniform(size=(3, 5)) / 5
  expected = []
  for b in range(3):
    mids = 0.5 * (s[b, 1:] + s[b, :-1])
    total = sum(w[b, i] * w[b, j] * abs(mids[i] - mids[j]) for i in range(5) for j in range(5))
    total += sum(w[b, i]**2 * (s[b, i + 1] - s[b, i]) for i in range(5)) / 3
    expected.append(total)
  assert float(reconstruction.distortion_loss(s, w)) == pytest.approx(np.mean(expected), rel=1e-5)


def test_weight_l2():
  params = {'a': jnp.ones((2, 2)) * 2., 'b': jnp.zeros(4)}
  assert float(reconstruction.weight_l2(params)) == pytest.approx(16. / 8.)
