"""Pure-functional reconstruction losses, PSNR bookkeeping and the distortion loss (ablation)."""

import jax
import jax.numpy as jnp
import numpy as np


def data_loss(rgb, target, lossmult):
  """Released normalization: sum over rays and channels / sum of lossmult [B, 1] (= 3x MSE)."""
  return jnp.sum(lossmult * (rgb - target)**2) / jnp.sum(lossmult)


def mse_to_psnr(mse):
  """PSNR in dB, -10 log10(mse), of a mean squared error on [0, 1] images; inf for 0.

  A jax array (traced in the training step) gives a jax array; anything else a float64 numpy value, the
  precision the evaluation reports.
  """
  if isinstance(mse, jax.Array):
    return -10. * jnp.log10(mse)
  with np.errstate(divide='ignore'):
    return -10. * np.log10(np.float64(mse))


def true_psnr(rgb, target, lossmult):
  """Per-channel PSNR of rgb, target [B, 3] weighted by lossmult [B, 1] (what we log)."""
  return mse_to_psnr(data_loss(rgb, target, lossmult) / rgb.shape[-1])


def distortion_loss(s_vals, weights):
  """Mip-NeRF 360 distortion of normalized endpoints s [B, S+1] and weights [B, S]; mean over rays."""
  mids = 0.5 * (s_vals[..., 1:] + s_vals[..., :-1])
  pairwise = jnp.abs(mids[..., :, None] - mids[..., None, :])
  inter = jnp.sum(weights[..., :, None] * weights[..., None, :] * pairwise, axis=(-2, -1))
  intra = jnp.sum(weights**2 * (s_vals[..., 1:] - s_vals[..., :-1]), axis=-1) / 3.
  return jnp.mean(inter + intra)


def weight_l2(params):
  """Mean squared parameter value (logged, and used when weight_decay_mult > 0)."""
  leaves = jax.tree.leaves(params)
  return sum(jnp.sum(x**2) for x in leaves) / sum(x.size for x in leaves)


def distortion_on(config) -> bool:
  """Whether Config asks for the distortion term (an ablation)."""
  return config.distortion_loss_mult > 0


def distortion_term(config, rendered: dict, batch, step) -> tuple:
  """(Config.distortion_loss_mult x the distortion of the fine level of the training pixels' rays, their samples'
  endpoints normalized to each ray's (annealed) near and far, {'loss_distortion'}) (losses/terms.py)."""
  del batch, step  # The rendered rays and samples only.
  pixels = rendered['rays']
  fine = pixels.history[-1]
  s_vals = (fine['t_vals'] - pixels.rays.near) / (pixels.rays.far - pixels.rays.near)
  loss = distortion_loss(s_vals, fine['weights'])
  return config.distortion_loss_mult * loss, {'loss_distortion': loss}
