"""The exact integer pointer arithmetic of FreeNeRF's frequency ramp (docs/numerics.md).

The released pointer is ptr = num/den * t/T + 1 in float64; here it is split exactly in integers so that a mask
computed under jit in int32/float32 equals the released one (the open group gets the float32 rounding of the
exact fraction). `freq_schedule.py` decides which features form a group and when the ramp applies.
"""

import jax.numpy as jnp

_LOW, _HIGH = 1e-8, 1. - 1e-8  # The released clip: a closed feature is 1e-8, never exactly 0.


def pointer_fits(num: int, den: int, end: int) -> bool:
  """Whether num * T and den * T fit the int32 / float32-exact ranges the ramp computes in."""
  return num * end < 2**31 and den * end < 2**24


def ramp(group, num: int, den: int, step, end: int):
  """Opens feature groups (group [L] int) left to right, ptr = num/den * t/T + 1 -> f32 [L].

  num*t = (den*T) * (ptr - 1) splits into an integer part n and a remainder r; group n + 1 gets r / (den*T).
  The cap ptr <= num/den (an integer group count) needs no code: when it applies every group is <= n.
  """
  if end == 0:
    return jnp.ones(group.shape, jnp.float32)
  if not pointer_fits(num, den, end):
    raise ValueError(f'Config.freq_reg_end = {end} is too large for the exact mask pointer '
                     f'(needs {num} * T < 2**31 and {den} * T < 2**24)')
  t = jnp.clip(jnp.asarray(step, jnp.int32), 0, end)
  n, r = jnp.divmod(num * t, den * end)
  frac = r.astype(jnp.float32) / jnp.float32(den * end)
  group = jnp.asarray(group, jnp.int32)
  mask = jnp.where(group <= n, 1., jnp.where(group == n + 1, frac, 0.))
  mask = jnp.clip(mask, _LOW, _HIGH)
  return jnp.where(t >= end, jnp.ones_like(mask), mask)
