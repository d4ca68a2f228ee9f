"""Tests of internal/evaluation/metrics.py against hand computations and a direct SSIM implementation."""

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from internal.evaluation import metrics


def _smooth_pair(seed=0, h=20, w=24):
  """A smooth image [h,w,3] and a noisy copy."""
  rng = np.random.default_rng(seed)
  y, x = np.mgrid[0:h, 0:w] / 10.
  gt = np.stack([0.5 + 0.4 * np.sin(x + c) * np.cos(y - c) for c in range(3)], -1)
  return gt + rng.normal(0., 0.05, gt.shape), gt


def _direct_ssim(a, b, data_range=1.):
  """Uniform 7x7 SSIM over valid windows with sample (n-1) covariance, averaged over channels."""
  c1, c2 = (0.01 * data_range)**2, (0.03 * data_range)**2
  scores = []
  for ch in range(a.shape[-1]):
    wa = sliding_window_view(a[..., ch], (7, 7)).reshape(-1, 49)
    wb = sliding_window_view(b[..., ch], (7, 7)).reshape(-1, 49)
    ma, mb = wa.mean(1), wb.mean(1)
    va, vb = wa.var(1, ddof=1), wb.var(1, ddof=1)
    cov = ((wa - ma[:, None]) * (wb - mb[:, None])).sum(1) / 48.
    s = (2 * ma * mb + c1) * (2 * cov + c2) / ((ma**2 + mb**2 + c1) * (va + vb + c2))
    scores.append(s.mean())
  return float(np.mean(scores))


def test_psnr_by_hand():
  gt = np.zeros((4, 6, 3))
  pred = gt.copy()
  pred[:2] = 0.1   # Half of the values: error 0.1; the other half: 0.3.
  pred[2:] = 0.3
  assert metrics.psnr(pred, gt) == pytest.approx(-10 * np.log10((0.01 + 0.09) / 2), abs=1e-12)
  assert metrics.psnr(gt + 0.1, gt) == pytest.approx(20., abs=1e-10)
  assert metrics.psnr(gt, gt) == np.inf


def test_psnr_is_float64_and_unclipped():
  gt = np.full((3, 3, 3), 0.999, np.float32)
  pred = np.full((3, 3, 3), 1.001, np.float32)   # Out of [0,1]: clipping would shrink the error to 0.001.
  expected = -10 * np.log10((np.float64(pred[0, 0, 0]) - np.float64(gt[0, 0, 0]))**2)
  assert metrics.psnr(pred, gt) == pytest.approx(expected, abs=1e-9)


def test_ssim_matches_direct_uniform_window():
  pred, gt = _smooth_pair()
  value = metrics.ssim(pred, gt)
  assert value == pytest.approx(_direct_ssim(pred, gt), abs=1e-9)
  assert abs(value - _direct_ssim(pred, gt, data_range=2.)) > 0.05   # data_range=1 really is used.
  assert metrics.ssim(gt, gt) == pytest.approx(1.)


def test_avg_error_by_hand():
  # 10^(-20/10) = 0.01, sqrt(1 - 0.96) = 0.2, lpips 0.5: geometric mean (0.001)^(1/3) = 0.1.
  assert metrics.avg_error(20., 0.96, 0.5) == pytest.approx(0.1, rel=1e-12)
  assert metrics.avg_error(20., 0.96, None) is None


def _masked_case():
  """16x16 images and a mask with 1, 0.5 and 0 regions; pred errs by 0.1 inside, by 0.5 elsewhere."""
  gt = np.full((16, 16, 3), 0.4)
  mask = np.zeros((16, 16, 3))
  mask[2:10, 2:10] = 1.
  mask[10:12, 2:10] = 0.5
  pred = gt + 0.5
  pred[2:10, 2:10] = gt[2:10, 2:10] + 0.1
  return pred, gt, mask


def test_dtu_masked_psnr_uses_only_mask_equal_one():
  pred, gt, mask = _masked_case()
  values = metrics.dtu_masked_metrics(pred, gt, mask)
  assert values['psnr_masked'] == pytest.approx(20., abs=1e-9)   # Only the 0.1 errors count.
  assert values['lpips_masked'] is None and values['avg_error_masked'] is None


def test_dtu_masked_ssim_and_lpips_use_white_composites():
  pred, gt, mask = _masked_case()
  seen = []
  values = metrics.dtu_masked_metrics(pred, gt, mask, lambda a, b: seen.append((a, b)) or 0.25)
  white_pred, white_gt = seen[0]
  assert white_pred[0, 0, 0] == 1. and white_gt[0, 0, 0] == 1.                # Background -> white.
  assert white_pred[11, 5, 1] == pytest.approx(0.9 * 0.5 + 0.5)              # Edge: blended.
  assert white_gt[11, 5, 1] == pytest.approx(0.4 * 0.5 + 0.5)
  assert white_pred[5, 5, 2] == pytest.approx(0.5)                           # Inside: unchanged.
  assert values['ssim_masked'] == pytest.approx(_direct_ssim(white_pred, white_gt), abs=1e-9)
  assert values['lpips_masked'] == 0.25
  expected_avg = (0.01 * np.sqrt(1 - values['ssim_masked']) * 0.25)**(1 / 3)
  assert values['avg_error_masked'] == pytest.approx(expected_avg, rel=1e-12)


def test_dtu_masked_identical_objects_give_perfect_ssim():
  pred, gt, mask = _masked_case()
  pred = np.where(mask > 0, gt, 0.9)   # Differs only where the mask is 0.
  values = metrics.dtu_masked_metrics(pred, gt, mask, lambda a, b: float(np.abs(a - b).max()))
  assert values['ssim_masked'] == pytest.approx(1.) and values['lpips_masked'] == 0.
  assert values['psnr_masked'] == np.inf


def test_image_metrics_keys_and_missing_lpips():
  pred, gt = _smooth_pair()
  values = metrics.image_metrics(pred, gt)
  assert set(values) == set(metrics.FULL_METRICS)
  assert values['lpips'] is None and values['avg_error'] is None
  assert values['psnr'] == metrics.psnr(pred, gt) and values['ssim'] == metrics.ssim(pred, gt)


def test_image_metrics_with_lpips_and_mask():
  pred, gt = _smooth_pair()
  mask = np.ones_like(gt)
  mask[:, :8] = 0.
  values = metrics.image_metrics(pred, gt, lambda a, b: 0.2, mask=mask)
  assert set(values) == set(metrics.FULL_METRICS) | set(metrics.MASKED_METRICS)
  assert values['avg_error'] == pytest.approx(metrics.avg_error(values['psnr'], values['ssim'], 0.2))
  assert values['psnr_masked'] == pytest.approx(metrics.psnr(pred[:, 8:], gt[:, 8:]))
