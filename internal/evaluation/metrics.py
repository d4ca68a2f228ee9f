"""Image metrics as the released FreeNeRF eval.py reports them; predictions are used unclipped.

Keys produced by `image_metrics`: FULL_METRICS always, MASKED_METRICS when a DTU mask is given. LPIPS entries
(and the avg_error built from them) are None when no LPIPS function is available: missing, never 0.
"""

from typing import Callable, Dict, Optional

import numpy as np
import skimage.metrics

from internal.evaluation import metric_registry
from internal.losses.reconstruction import mse_to_psnr

LpipsFn = Callable[[np.ndarray, np.ndarray], float]
FULL_METRICS = metric_registry.names(metric_registry.FULL)
MASKED_METRICS = metric_registry.names(metric_registry.MASKED)


def _f64(x) -> np.ndarray:
  """Any array -> float64 numpy array."""
  return np.asarray(x, dtype=np.float64)


def psnr(pred, gt) -> float:
  """PSNR of pred [H,W,3] vs gt [H,W,3] in float64 over all H*W*3 values."""
  return float(mse_to_psnr(np.mean((_f64(pred) - _f64(gt))**2)))


def ssim(pred, gt) -> float:
  """SSIM of pred [H,W,3] vs gt [H,W,3]: skimage, 7x7 uniform window, sample covariance, data_range 1."""
  return float(skimage.metrics.structural_similarity(
      _f64(pred), _f64(gt), channel_axis=-1, data_range=1.0, win_size=7, gaussian_weights=False,
      use_sample_covariance=True, K1=0.01, K2=0.03))


def avg_error(psnr_value: Optional[float], ssim_value: Optional[float],
              lpips_value: Optional[float]) -> Optional[float]:
  """Geometric mean of 10^(-psnr/10), sqrt(1 - ssim), lpips; None when any input is None."""
  if psnr_value is None or ssim_value is None or lpips_value is None:
    return None
  errors = np.array([10.**(-psnr_value / 10.), np.sqrt(1. - ssim_value), lpips_value])
  with np.errstate(divide='ignore'):  # A zero error gives a geometric mean of 0.
    return float(np.exp(np.mean(np.log(errors))))


def _full_metrics(pred, gt, lpips_fn: Optional[LpipsFn]) -> Dict[str, Optional[float]]:
  """psnr, ssim, lpips, avg_error of pred [H,W,3] vs gt [H,W,3] (lpips None without lpips_fn)."""
  values = {'psnr': psnr(pred, gt), 'ssim': ssim(pred, gt)}
  values['lpips'] = None if lpips_fn is None else float(lpips_fn(pred, gt))
  values['avg_error'] = avg_error(values['psnr'], values['ssim'], values['lpips'])
  return values


def white_composite(img, mask) -> np.ndarray:
  """img [H,W,3] * mask [H,W,3 or 1] + (1 - mask): background set to white."""
  m = _f64(mask)
  return _f64(img) * m + (1. - m)


def masked_psnr(pred, gt, mask) -> float:
  """PSNR of pred [H,W,3] vs gt [H,W,3] over the values whose mask [H,W,3 or 1] is exactly 1 (nan if none)."""
  pred, gt = _f64(pred), _f64(gt)
  inside = np.broadcast_to(_f64(mask), pred.shape) == 1.
  return float(mse_to_psnr(np.mean((pred[inside] - gt[inside])**2) if inside.any() else np.nan))


def dtu_masked_metrics(pred, gt, mask, lpips_fn: Optional[LpipsFn] = None) -> Dict[str, Optional[float]]:
  """DTU object metrics of pred [H,W,3] vs gt [H,W,3] with mask [H,W,3 or 1] in [0,1]; keys MASKED_METRICS.

  psnr_masked averages the squared error over the values whose mask is exactly 1 (nan if there are none);
  ssim/lpips_masked compare both images with the background composited to white.
  """
  white_pred, white_gt = white_composite(pred, mask), white_composite(gt, mask)
  values = {'psnr_masked': masked_psnr(pred, gt, mask), 'ssim_masked': ssim(white_pred, white_gt)}
  values['lpips_masked'] = None if lpips_fn is None else float(lpips_fn(white_pred, white_gt))
  values['avg_error_masked'] = avg_error(
      values['psnr_masked'], values['ssim_masked'], values['lpips_masked'])
  return values


def image_metrics(pred, gt, lpips_fn: Optional[LpipsFn] = None, mask=None) -> Dict[str, Optional[float]]:
  """Metrics of pred [H,W,3] vs gt [H,W,3]: FULL_METRICS, plus MASKED_METRICS when mask [H,W,3] is given."""
  values = _full_metrics(pred, gt, lpips_fn)
  if mask is not None:
    values.update(dtu_masked_metrics(pred, gt, mask, lpips_fn))
  return values
