"""COLMAP's pinhole and radial-tangential camera models: projection with distortion and its inverse (Newton).

Every supported model is written as OpenCV's eight parameters (fx, fy, cx, cy, k1, k2, p1, p2): SIMPLE_PINHOLE
(f, cx, cy), PINHOLE (fx, fy, cx, cy), SIMPLE_RADIAL (f, cx, cy, k), RADIAL (f, cx, cy, k1, k2) and OPENCV set
the others to 0. A normalized point (u, v) (camera x / z, y / z) is distorted as COLMAP does:
  r2 = u^2 + v^2, radial = k1 r2 + k2 r2^2,
  u' = u + u radial + 2 p1 u v + p2 (r2 + 2 u^2),   v' = v + v radial + p1 (r2 + 2 v^2) + 2 p2 u v,
and lands on pixel (fx u' + cx, fy v' + cy), the top-left pixel's centre being (0.5, 0.5).
"""

from typing import Sequence, Tuple

import numpy as np

SUPPORTED = ('SIMPLE_PINHOLE', 'PINHOLE', 'SIMPLE_RADIAL', 'RADIAL', 'OPENCV')
NEWTON_STEPS = 20  # Enough for machine precision at any distortion a calibrated camera has (tests).


class UnsupportedCameraError(ValueError):
  """A camera model whose distortion this project does not invert."""


def opencv_params(model: str, params: Sequence[float]) -> np.ndarray:
  """[8] (fx, fy, cx, cy, k1, k2, p1, p2) of a supported COLMAP camera model and its parameters."""
  p = [float(v) for v in params]
  if model == 'SIMPLE_PINHOLE':
    return np.array([p[0], p[0], p[1], p[2], 0., 0., 0., 0.])
  if model == 'PINHOLE':
    return np.array(p[:4] + [0., 0., 0., 0.])
  if model == 'SIMPLE_RADIAL':
    return np.array([p[0], p[0], p[1], p[2], p[3], 0., 0., 0.])
  if model == 'RADIAL':
    return np.array([p[0], p[0], p[1], p[2], p[3], p[4], 0., 0.])
  if model == 'OPENCV':
    return np.array(p[:8])
  raise UnsupportedCameraError(f'camera model {model!r} is not supported; expected one of {list(SUPPORTED)}')


def scaled(params: np.ndarray, factor: float) -> np.ndarray:
  """params [8] for images downsampled by factor (focal lengths and principal point / factor)."""
  return np.concatenate([params[:4] / factor, params[4:]])


def _coefficients(params) -> tuple:
  """(k1, k2, p1, p2) [...] of params [..., 8]."""
  return tuple(params[..., i] for i in range(4, 8))


def distort(params, u, v) -> Tuple:
  """Distorted normalized coordinates (u', v') [...] of (u, v) [...] (params [..., 8] broadcast)."""
  k1, k2, p1, p2 = _coefficients(params)
  r2 = u * u + v * v
  radial = k1 * r2 + k2 * r2 * r2
  return (u + u * radial + 2. * p1 * u * v + p2 * (r2 + 2. * u * u),
          v + v * radial + p1 * (r2 + 2. * v * v) + 2. * p2 * u * v)


def _jacobian(params, u, v) -> tuple:
  """(du'/du, du'/dv, dv'/du, dv'/dv) [...] of distort at (u, v)."""
  k1, k2, p1, p2 = _coefficients(params)
  r2 = u * u + v * v
  radial = k1 * r2 + k2 * r2 * r2
  d_radial = 2. * (k1 + 2. * k2 * r2)  # d radial / du = d_radial * u, likewise for v.
  return (1. + radial + d_radial * u * u + 2. * p1 * v + 6. * p2 * u,
          d_radial * u * v + 2. * p1 * u + 2. * p2 * v,
          d_radial * u * v + 2. * p1 * u + 2. * p2 * v,
          1. + radial + d_radial * v * v + 6. * p1 * v + 2. * p2 * u)


def undistort(params, ud, vd, xp=np) -> Tuple:
  """(u, v) [...] with distort(u, v) = (ud, vd): Newton's method from (ud, vd) (numpy in float64, or jax.numpy)."""
  u, v = (xp.asarray(x, np.float64 if xp is np else None) for x in (ud, vd))
  if xp is np and not np.any(params[..., 4:]):
    return u, v
  for _ in range(NEWTON_STEPS):
    fu, fv = distort(params, u, v)
    ru, rv = fu - ud, fv - vd
    a, b, c, d = _jacobian(params, u, v)
    det = a * d - b * c
    u, v = u - (d * ru - b * rv) / det, v - (a * rv - c * ru) / det
  return u, v


def pixel_to_normalized(params, x, y, xp=np) -> Tuple:
  """Undistorted normalized coordinates (u, v) [...] of pixel positions (x, y) [...] (COLMAP's convention) of
  cameras params [..., 8]."""
  real = np.float64 if xp is np else None
  return undistort(params, (xp.asarray(x, real) - params[..., 2]) / params[..., 0],
                   (xp.asarray(y, real) - params[..., 3]) / params[..., 1], xp)
