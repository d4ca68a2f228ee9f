"""FreeNeRF's occlusion regularization: penalize density near the camera (floaters)."""

import jax
import jax.numpy as jnp


def occlusion_mask(rgb, reg_range: int, wb_prior: bool, wb_range: int):
  """Mask [B, S] of penalized samples: the first reg_range, plus black/white samples among the first wb_range."""
  num_samples = rgb.shape[-2]
  index = jnp.arange(num_samples)
  mask = jnp.zeros(rgb.shape[:-1], jnp.float32)
  if wb_prior:
    grey = jnp.mean(rgb, axis=-1)
    black_or_white = (grey > 0.99) | (grey < 0.01)
    mask = jnp.where(black_or_white & (index < wb_range), 1., mask)
  if reg_range > 0:
    mask = jnp.where(index < reg_range, 1., mask)
  return jax.lax.stop_gradient(mask)


def occlusion_loss(density, rgb, reg_range: int, wb_prior: bool, wb_range: int):
  """Mean over all B x S entries of density [B, S] on the masked samples (rgb [B, S, 3] per sample)."""
  return jnp.mean(density * occlusion_mask(rgb, reg_range, wb_prior, wb_range))


def is_on(config) -> bool:
  """Whether Config asks for the occlusion term."""
  return config.occ_reg_loss_mult > 0


def term(config, rendered: dict, batch, step) -> tuple:
  """(Config.occ_reg_loss_mult x the occlusion loss of the fine level's samples of the training pixels' rays,
  {'loss_occ'}) (losses/terms.py)."""
  del batch, step  # The samples' density and colour only.
  fine = rendered['rays'].history[-1]
  loss = occlusion_loss(fine['density'], fine['rgb'], config.occ_reg_range, config.occ_wb_prior, config.occ_wb_range)
  return config.occ_reg_loss_mult * loss, {'loss_occ': loss}
