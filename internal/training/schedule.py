"""Schedules of the training step: learning rate with sine warm-up, resampling padding."""

import jax.numpy as jnp


def log_lerp(t, v0, v1):
  """Log-linear interpolation between v0 > 0 and v1 > 0 at t in [0, 1]."""
  return jnp.exp(jnp.log(v0) * (1 - t) + jnp.log(v1) * t)


def learning_rate(step, lr_init, lr_final, max_steps, lr_delay_steps=0, lr_delay_mult=1.):
  """Log-linear decay lr_init -> lr_final over max_steps, scaled by a sine warm-up from lr_delay_mult."""
  if lr_delay_steps > 0:
    warm = jnp.clip(step / lr_delay_steps, 0., 1.)
    delay = lr_delay_mult + (1 - lr_delay_mult) * jnp.sin(0.5 * jnp.pi * warm)
  else:
    delay = 1.
  return delay * log_lerp(jnp.clip(step / max_steps, 0., 1.), lr_init, lr_final)


def config_learning_rate(config, step):
  """The learning rate of Config at a (possibly traced) step."""
  return learning_rate(step, config.lr_init, config.lr_final, config.max_steps,
                       config.lr_delay_steps, config.lr_delay_mult)


def resample_padding(config, step):
  """Padding added to the blurred coarse weights at step."""
  return log_lerp(jnp.clip(step / config.max_steps, 0., 1.),
                  config.resample_padding_init, config.resample_padding_final)
