"""Sampling distances along rays: stratified (coarse), inverse-CDF resampling (mip-NeRF) and NeRF's importance samples."""

import jax
import jax.numpy as jnp

_EPS = float(jnp.finfo(jnp.float32).eps)
_EVEN_EPS = 1e-5  # mip-NeRF's target weight sum for the 'even' padding rule.
PDF_PADDINGS = ('released', 'even')


def stratified_t_vals(key, near, far, num_samples):
  """S+1 endpoints in [near, far] ([B,1] each) -> t [B,S+1], jittered between midpoints if key."""
  steps = jnp.linspace(0., 1., num_samples + 1)
  t = near + (far - near) * steps
  if key is None:
    return t
  mids = 0.5 * (t[..., 1:] + t[..., :-1])
  upper = jnp.concatenate([mids, t[..., -1:]], axis=-1)
  lower = jnp.concatenate([t[..., :1], mids], axis=-1)
  return lower + (upper - lower) * jax.random.uniform(key, t.shape)


def blur_weights(weights, padding):
  """Edge-padded 2-tap max then 2-tap mean of weights [B,S], plus padding -> [B,S]."""
  w_pad = jnp.concatenate([weights[..., :1], weights, weights[..., -1:]], axis=-1)
  w_max = jnp.maximum(w_pad[..., :-1], w_pad[..., 1:])
  return 0.5 * (w_max[..., :-1] + w_max[..., 1:]) + padding


def invert_cdf(u, cdf, bins):
  """Piecewise-linear inverse of cdf [B,S+1] (non-decreasing, 0 first) over bins [B,S+1] at u [B,n]."""
  num_bins = cdf.shape[-1] - 1
  below = jnp.sum(cdf[..., None, :] <= u[..., :, None], axis=-1) - 1
  idx = jnp.clip(below, 0, num_bins - 1)
  cdf0 = jnp.take_along_axis(cdf, idx, axis=-1)
  cdf1 = jnp.take_along_axis(cdf, idx + 1, axis=-1)
  bin0 = jnp.take_along_axis(bins, idx, axis=-1)
  bin1 = jnp.take_along_axis(bins, idx + 1, axis=-1)
  width = cdf1 - cdf0
  frac = jnp.clip((u - cdf0) / jnp.where(width > 0, width, 1.), 0., 1.)
  return bin0 + frac * (bin1 - bin0)


def _sample_u(key, shape, num_samples):
  """Sorted u in [0,1): stratified-jittered if key else linspace(0, 1-eps); -> shape + [n]."""
  if key is None:
    return jnp.broadcast_to(jnp.linspace(0., 1. - _EPS, num_samples), shape + (num_samples,))
  step = 1. / num_samples
  jitter = jax.random.uniform(key, shape + (num_samples,), maxval=step - _EPS)
  return jnp.minimum(jnp.arange(num_samples) * step + jitter, 1. - _EPS)


def pad_weights(weights, rule='released'):
  """Weights [B,S] padded so that all-zero rows give a uniform pdf (docs/numerics.md) -> [B,S]."""
  weight_sum = jnp.sum(weights, axis=-1, keepdims=True)
  if rule == 'released':  # Below float32 eps, the whole deficit is added to every bin.
    return weights + jnp.maximum(0., _EPS - weight_sum)
  if rule == 'even':  # Below 1e-5, the deficit is spread evenly over the bins (sum becomes 1e-5).
    return weights + jnp.maximum(0., _EVEN_EPS - weight_sum) / weights.shape[-1]
  raise ValueError(f'MipNerfModel.pdf_padding = {rule!r}; expected one of {list(PDF_PADDINGS)}')


def sample_pdf(key, bins, weights, num_samples, padding='released'):
  """Inverse-CDF samples of the piecewise-constant pdf (bins [B,S+1], weights [B,S]) -> [B,n]."""
  weights = pad_weights(weights, padding)
  pdf = weights / jnp.sum(weights, axis=-1, keepdims=True)
  cdf = jnp.minimum(1., jnp.cumsum(pdf[..., :-1], axis=-1))
  zeros, ones = jnp.zeros_like(cdf[..., :1]), jnp.ones_like(cdf[..., :1])
  cdf = jnp.concatenate([zeros, cdf, ones], axis=-1)
  u = _sample_u(key, bins.shape[:-1], num_samples)
  return invert_cdf(u, cdf, bins)


def resample_t_vals(key, t_vals, weights, padding, pdf_padding='released'):
  """New sorted endpoints [B,S+1] drawn from blurred weights [B,S] over t_vals [B,S+1]; no gradient."""
  blurred = blur_weights(weights, padding)
  new_t = sample_pdf(key, t_vals, blurred, t_vals.shape[-1], pdf_padding)
  return jax.lax.stop_gradient(jnp.sort(new_t, axis=-1))


NERF_WEIGHT_PADDING = 1e-5  # NeRF adds this to every weight before building its pdf.


def importance_samples(key, t_points, weights, num_samples):
  """NeRF's hierarchical samples [B,n] from sample points t_points [B,S] and their weights [B,S]; no gradient.

  The pdf lives on the S-1 intervals between midpoints of t_points, with the interior weights [1:-1] padded by
  NERF_WEIGHT_PADDING; u is iid uniform when key is given, else linspace(0, 1) (NeRF's deterministic pass).
  """
  bins = 0.5 * (t_points[..., 1:] + t_points[..., :-1])
  padded = weights[..., 1:-1] + NERF_WEIGHT_PADDING
  pdf = padded / jnp.sum(padded, axis=-1, keepdims=True)
  cdf = jnp.concatenate([jnp.zeros_like(pdf[..., :1]), jnp.cumsum(pdf, axis=-1)], axis=-1)
  shape = t_points.shape[:-1] + (num_samples,)
  if key is None:
    u = jnp.broadcast_to(jnp.linspace(0., 1., num_samples), shape)
  else:
    u = jax.random.uniform(key, shape)
  return jax.lax.stop_gradient(invert_cdf(u, cdf, bins))
