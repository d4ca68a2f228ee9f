"""FreeNeRF's frequency-regularization masks over the encoding features (paper Sec. 3.2; docs/numerics.md)."""

import numpy as np
import jax.numpy as jnp

from internal.models import encoding

_LOW, _HIGH = 1e-8, 1. - 1e-8
LAYOUTS = ('released', 'paper')  # Config.freq_mask_layout: released_mask or paper_mask.


def _ramp_mask(group, num, den, step, end):
  """Opens feature groups (group [L] int) left to right, ptr = num/den * t/T + 1 -> f32 [L].

  The pointer is split exactly in integers, num*t = (den*T) * (ptr - 1) with integer part n and
  remainder r; the open group gets r / (den*T), the float32 rounding of the exact fraction. The cap
  ptr <= num/den (an integer group count) needs no code: when it applies every group is <= n.
  """
  if end == 0:
    return jnp.ones(group.shape, jnp.float32)
  if num * end >= 2**31 or den * end >= 2**24:
    raise ValueError(f'Config.freq_reg_end = {end} is too large for the exact mask pointer '
                     f'(needs {num} * T < 2**31 and {den} * T < 2**24)')
  t = jnp.clip(jnp.asarray(step, jnp.int32), 0, end)
  n, r = jnp.divmod(num * t, den * end)
  frac = r.astype(jnp.float32) / jnp.float32(den * end)
  group = jnp.asarray(group, jnp.int32)
  mask = jnp.where(group <= n, 1., jnp.where(group == n + 1, frac, 0.))
  mask = jnp.clip(mask, _LOW, _HIGH)
  return jnp.where(t >= end, jnp.ones_like(mask), mask)


def released_mask(length, step, end):
  """Released mask: chunks of 3 features open left to right; f32 [length]."""
  return _ramp_mask(np.arange(length) // 3, length, 3, step, end)


def paper_mask(num_degrees, step, end, num_coords=3):
  """Paper-style mask: identity, then sin and cos of each degree together; f32 [encoding.width(D, C)]."""
  _, degree, _ = encoding.feature_layout(num_degrees, num_coords, append_identity=True)
  return _ramp_mask(degree + 1, num_degrees + 1, 1, step, end)


def fixed_ratio_mask(length, ratio):
  """Ablation mask: the first int(length*ratio) features 1, the rest 0; f32 [length]."""
  return jnp.asarray(np.arange(length) < int(length * ratio), jnp.float32)


def encoding_masks(step, *, freq_reg, freq_reg_end, layout, max_vis_freq_ratio, num_deg_point, num_deg_view):
  """Masks for the point [width(Dp)] and view [width(Dv)] encodings, or (None, None) without freq_reg.

  As in the released code, the fixed visible-ratio ablation (max_vis_freq_ratio > 0) acts only under freq_reg.
  """
  if not freq_reg:
    return None, None
  len_point, len_view = encoding.width(num_deg_point), encoding.width(num_deg_view)
  if max_vis_freq_ratio > 0:
    return (fixed_ratio_mask(len_point, max_vis_freq_ratio),
            fixed_ratio_mask(len_view, max_vis_freq_ratio))
  if freq_reg_end == 0:
    return None, None
  if layout == 'released':
    return (released_mask(len_point, step, freq_reg_end),
            released_mask(len_view, step, freq_reg_end))
  if layout == 'paper':
    return (paper_mask(num_deg_point, step, freq_reg_end),
            paper_mask(num_deg_view, step, freq_reg_end))
  raise ValueError(f'Config.freq_mask_layout = {layout!r}; expected one of {list(LAYOUTS)}')
