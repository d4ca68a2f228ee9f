"""Gradient clipping as released (by value, then by global norm) and the Adam transform."""

import jax
import jax.numpy as jnp
import optax


def global_norm(tree):
  """L2 norm over every leaf of a tree."""
  return jnp.sqrt(sum(jnp.sum(x**2) for x in jax.tree.leaves(tree)))


def all_finite(tree):
  """True when every entry of every leaf is finite."""
  return jnp.all(jnp.array([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]))


def clip_gradients(grads, max_val: float, max_norm: float):
  """Clips by value to [-max_val, max_val], then by global norm (0 disables either); returns (grads, stats)."""
  stats = {'grad_norm_raw': global_norm(grads)}
  if max_val > 0:
    grads = jax.tree.map(lambda g: jnp.clip(g, -max_val, max_val), grads)
  stats['grad_abs_max'] = jnp.max(jnp.array([jnp.max(jnp.abs(g)) for g in jax.tree.leaves(grads)]))
  norm = global_norm(grads)
  stats['grad_norm'] = norm
  if max_norm > 0:
    scale = jnp.minimum(1., max_norm / (jnp.finfo(jnp.float32).eps + norm))
    grads = jax.tree.map(lambda g: g * scale, grads)
  stats['grad_norm_clipped'] = global_norm(grads)
  return grads, stats


def adam(eps: float):
  """Adam moments as flax.optim.Adam (0.9, 0.999, eps); the learning rate is applied by the caller."""
  return optax.scale_by_adam(b1=0.9, b2=0.999, eps=eps, eps_root=0.)
