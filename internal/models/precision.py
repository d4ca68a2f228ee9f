"""The MLP's numeric precision (Config.precision): compute dtype and matmul precision of each setting."""

import jax
import jax.numpy as jnp

# 'float32': float32 everywhere, matmuls at HIGHEST precision (true float32 on every backend).
# 'default': float32 arrays, the backend's default matmul precision (TF32 on NVIDIA Ampere and later;
#            the same as 'float32' on CPU).
# 'bfloat16': parameters stay float32 and are cast at use; the MLP's inputs, activations and matmuls are
#             bfloat16; density and rgb come back as float32 for volume rendering and the losses.
# 'auto' (the default): 'float32' on a CPU, where the released numerics are checked; 'bfloat16' on an accelerator,
#             where a training step took 0.6x TF32's time, its test PSNR 0.7 dB above TF32's, on one H100
#             (results/gpu/h100_2026-11-26/README.md, 'The precision trade').
PRECISIONS = ('float32', 'default', 'bfloat16')
CHOICES = ('auto',) + PRECISIONS
_SETTINGS = {'float32': (jnp.float32, jax.lax.Precision.HIGHEST),
             'default': (jnp.float32, None),
             'bfloat16': (jnp.bfloat16, None)}


def resolve(name: str, backend: str = '') -> str:
  """The precision a Config.precision value means on a backend ('cpu', 'gpu', ...; '' = this process's), one of
  PRECISIONS."""
  if name == 'auto':
    return 'float32' if (backend or jax.default_backend()) == 'cpu' else 'bfloat16'
  if name not in _SETTINGS:
    raise ValueError(f'Config.precision = {name!r}; expected one of {list(CHOICES)}')
  return name


def settings(name: str):
  """(compute dtype, matmul precision or None for the backend default) of a Config.precision value."""
  return _SETTINGS[resolve(name)]


@jax.custom_vjp
def low_precision_matmul(x, kernel):
  """x [..., d] @ kernel [d, o] in x's (lower) dtype; the kernel's gradient comes out float32, not rounded."""
  return jnp.matmul(x, kernel.astype(x.dtype))


def _matmul_forward(x, kernel):
  low = kernel.astype(x.dtype)
  return jnp.matmul(x, low), (x, low)


def _rows(a):
  return a.reshape((-1, a.shape[-1]))


def _matmul_backward(residuals, g):
  x, low = residuals
  # Accumulated over every row in float32 and kept float32: rounding the sum to bfloat16 would cost the weight
  # gradient 16 of its 24 bits before the float32 optimizer sees it.
  kernel_grad = jax.lax.dot_general(_rows(x), _rows(g), (((0,), (0,)), ((), ())), preferred_element_type=jnp.float32)
  return jnp.matmul(g, low.T), kernel_grad


low_precision_matmul.defvjp(_matmul_forward, _matmul_backward)


@jax.custom_vjp
def add_low_precision_bias(x, bias):
  """x [..., o] + bias [o] in x's (lower) dtype; the bias's gradient summed over the rows in float32."""
  return x + bias.astype(x.dtype)


def _bias_forward(x, bias):
  return add_low_precision_bias(x, bias), None


def _bias_backward(_, g):
  return g, jnp.sum(_rows(g), axis=0, dtype=jnp.float32)


add_low_precision_bias.defvjp(_bias_forward, _bias_backward)
