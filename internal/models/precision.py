"""The MLP's numeric precision (Config.precision): compute dtype and matmul precision of each setting."""

import jax
import jax.numpy as jnp

# 'float32': float32 everywhere, matmuls at HIGHEST precision (true float32 on every backend).
# 'default': float32 arrays, the backend's default matmul precision (TF32 on NVIDIA Ampere and later;
#            the same as 'float32' on CPU).
# 'bfloat16': parameters stay float32 and are cast at use; the MLP's inputs, activations and matmuls are
#             bfloat16; density and rgb come back as float32 for volume rendering and the losses.
PRECISIONS = ('float32', 'default', 'bfloat16')
_SETTINGS = {'float32': (jnp.float32, jax.lax.Precision.HIGHEST),
             'default': (jnp.float32, None),
             'bfloat16': (jnp.bfloat16, None)}


def settings(name: str):
  """(compute dtype, matmul precision or None for the backend default) of a Config.precision value."""
  if name not in _SETTINGS:
    raise ValueError(f'Config.precision = {name!r}; expected one of {list(PRECISIONS)}')
  return _SETTINGS[name]
