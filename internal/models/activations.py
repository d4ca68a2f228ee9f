"""ReLU whose backward pass reads its output: the pre-activation need not be kept for the gradient.

jax's relu differentiates through its input (the gradient passes where x > 0), so a step keeps each layer's
pre-activation, or a mask of it, until the backward pass. relu(x) > 0 exactly where x > 0, so the gradient can be
read from the output, which the next layer's weight gradient keeps anyway: the same numbers, bit for bit
(NaN inputs included: no gradient passes either way). A step variant (MLP.net_activation = @relu_from_output)
whose worth is measured on a GPU by bench.step_variants.
"""

import jax
import jax.numpy as jnp


@jax.custom_vjp
def relu_from_output(x):
  """max(x, 0) [...] of x [...], differentiated through its output."""
  return jnp.maximum(x, 0)


def _forward(x):
  y = jnp.maximum(x, 0)
  return y, y


def gradient_from_output(y, g):
  """ReLU's gradient [...]: g [...] where its output y [...] > 0, else 0 (NaN outputs pass none, as jax's relu)."""
  return jnp.where(y > 0, g, jnp.zeros_like(g))


def _backward(y, g):
  return (gradient_from_output(y, g),)


relu_from_output.defvjp(_forward, _backward)
