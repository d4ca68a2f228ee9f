"""FreeNeRF's frequency regularization (paper Sec. 3.2): which encoding features are visible at a step.

Four settings decide it, all `Config` fields:
- `freq_reg` (bool): the switch. Off: no mask, every frequency visible from step 0 (mip-NeRF).
- `freq_reg_end` (int, T): the step at which the last band opens; the visible band grows linearly from the
  lowest frequencies at step 0 to all at T. 0 with `freq_reg` on: no ramp (all visible), unless the ratio below
  is set. The paper: T = 0.9 / 0.7 / 0.5 of the steps for 3 / 6 / 9 views; Blender T = 0.5 x steps.
- `max_vis_freq_ratio` (float in [0, 1]): the fixed visible-ratio ablation (paper Fig. 2): the first
  int(L * ratio) features stay visible for the whole run, the rest hidden; acts only under `freq_reg` (as
  released) and then replaces the ramp. 0 = off.
- `freq_mask_layout`: 'released' opens 3 features at a time left to right over the model's feature order (paper
  eq. 3's "3 bits at a time"; on mip-NeRF's block order every sin band opens before any cos band; on NeRF's
  interleaved order this is exactly the Blender code's rule, a band's sin one group before its cos); 'paper'
  opens the identity, then sin and cos of one degree together (a band at a time, our variant).
The released name `warmup_end` is read as `freq_reg_end` (internal/config_loader.py).

The ramp's pointer (docs/numerics.md): the released ptr = num/den * t/T + 1 in float64 is split exactly in
integers, so that a mask computed under jit in int32/float32 equals the released one (the open group gets the
float32 rounding of the exact fraction).
"""

import warnings

import numpy as np
import jax.numpy as jnp

from internal.configs import Config
from internal.models import coarse_to_fine, encoding

LAYOUTS = ('released', 'paper')  # Config.freq_mask_layout: released_mask or paper_mask.
IDENTITY_WIDTH = 3  # The raw coordinates that lead both feature orders (encoding.feature_layout).
_LOW, _HIGH = 1e-8, 1. - 1e-8  # The released clip: a closed feature is 1e-8, never exactly 0.


def pointer_fits(num: int, den: int, end: int) -> bool:
  """Whether num * T and den * T fit the int32 / float32-exact ranges the ramp computes in."""
  return num * end < 2**31 and den * end < 2**24


def _check_pointer(end: int, groups, what: str = '') -> None:
  """Raises a ValueError naming Config.freq_reg_end when T = end is too large for a (num, den) of groups."""
  if not all(pointer_fits(num, den, end) for num, den in groups):
    raise ValueError(f'Config.freq_reg_end = {end} is too large for the exact mask pointer{what} '
                     f'(at most {_max_end(groups)})')


def ramp(group, num: int, den: int, step, end: int):
  """Opens feature groups (group [L] int) left to right, ptr = num/den * t/T + 1 -> f32 [L].

  num*t = (den*T) * (ptr - 1) splits into an integer part n and a remainder r; group n + 1 gets r / (den*T).
  The cap ptr <= num/den (an integer group count) needs no code: when it applies every group is <= n.
  """
  if end == 0:
    return jnp.ones(group.shape, jnp.float32)
  _check_pointer(end, [(num, den)])
  t = jnp.clip(jnp.asarray(step, jnp.int32), 0, end)
  n, r = jnp.divmod(num * t, den * end)
  frac = r.astype(jnp.float32) / jnp.float32(den * end)
  group = jnp.asarray(group, jnp.int32)
  mask = jnp.where(group <= n, 1., jnp.where(group == n + 1, frac, 0.))
  mask = jnp.clip(mask, _LOW, _HIGH)
  return jnp.where(t >= end, jnp.ones_like(mask), mask)


def released_mask(length, step, end):
  """Released mask: chunks of 3 features open left to right; f32 [length]."""
  return ramp(np.arange(length) // 3, length, 3, step, end)


def paper_mask(num_degrees, step, end, num_coords=3, interleaved=False):
  """Paper-style mask: identity, then sin and cos of each degree together; f32 [encoding.width(D, C)].

  interleaved: for NeRF's interleaved feature order, else mip-NeRF's block order.
  """
  _, degree, _ = encoding.feature_layout(num_degrees, num_coords, append_identity=True, interleaved=interleaved)
  return ramp(degree + 1, num_degrees + 1, 1, step, end)


def fixed_ratio_mask(length, ratio):
  """Ablation mask: the first int(length*ratio) features 1, the rest 0; f32 [length]."""
  return jnp.asarray(np.arange(length) < int(length * ratio), jnp.float32)


def encoding_masks(step, *, freq_reg, freq_reg_end, layout, max_vis_freq_ratio, num_deg_point, num_deg_view,
                   interleaved=False):
  """Masks for the point [width(Dp)] and view [width(Dv)] encodings, or (None, None) when nothing is masked."""
  if not freq_reg:
    return None, None
  len_point, len_view = encoding.width(num_deg_point), encoding.width(num_deg_view)
  if max_vis_freq_ratio > 0:
    return fixed_ratio_mask(len_point, max_vis_freq_ratio), fixed_ratio_mask(len_view, max_vis_freq_ratio)
  if freq_reg_end == 0:
    return None, None
  if layout == 'released':
    return released_mask(len_point, step, freq_reg_end), released_mask(len_view, step, freq_reg_end)
  if layout == 'paper':
    return (paper_mask(num_deg_point, step, freq_reg_end, interleaved=interleaved),
            paper_mask(num_deg_view, step, freq_reg_end, interleaved=interleaved))
  raise ValueError(f'Config.freq_mask_layout = {layout!r}; expected one of {list(LAYOUTS)}')


def masks_at(config: Config, degrees, step, interleaved=False):
  """Masks (point, view) of Config for the encoding degrees (point, view) at a (possibly traced) step.

  (None, None) when off; degrees is the model's `model.encoding_degrees()`, interleaved its feature order.
  """
  num_deg_point, num_deg_view = degrees
  return encoding_masks(step, freq_reg=config.freq_reg, freq_reg_end=config.freq_reg_end,
                        layout=config.freq_mask_layout, max_vis_freq_ratio=config.max_vis_freq_ratio,
                        num_deg_point=num_deg_point, num_deg_view=num_deg_view, interleaved=interleaved)


def model_masks(config: Config, model, step):
  """masks_at for a model (MipNerfModel or NerfModel): its encoding degrees, feature order and point identity,
  times BARF's coarse-to-fine weights where Config.coarse_to_fine is on (coarse_to_fine.py).

  Without the raw coordinates (`point_identity()` False) the point mask is the full encoding's mask less its
  identity entries (the first 3 in either order), so every frequency opens at the same step as with them.
  """
  degrees, interleaved = model.encoding_degrees(), model.interleaved_encoding
  masks = masks_at(config, degrees, step, interleaved)
  weights = coarse_to_fine.weights_at(config, degrees, step, interleaved)
  mask_point, mask_view = (m if w is None else w if m is None else m * w for m, w in zip(masks, weights))
  if mask_point is not None and not model.point_identity():
    mask_point = mask_point[IDENTITY_WIDTH:]
  return mask_point, mask_view


def check_settings(config: Config, degrees) -> None:
  """Raises a ValueError naming the setting (warns for legal but odd ones) before any work is done."""
  if config.freq_mask_layout not in LAYOUTS:
    raise ValueError(f'Config.freq_mask_layout = {config.freq_mask_layout!r}; expected one of {list(LAYOUTS)}')
  if not 0. <= config.max_vis_freq_ratio <= 1.:
    raise ValueError(f'Config.max_vis_freq_ratio = {config.max_vis_freq_ratio}; expected in [0, 1]')
  if config.max_vis_freq_ratio > 0 and not config.freq_reg:
    raise ValueError(f'Config.max_vis_freq_ratio = {config.max_vis_freq_ratio} acts only under the frequency '
                     'regularizer, as released; set Config.freq_reg = True (with Config.freq_reg_end = 0 for the '
                     'fixed visible ratio alone) or leave the ratio at 0')
  if not config.freq_reg:
    return
  groups = [(encoding.width(d), 3) if config.freq_mask_layout == 'released' else (d + 1, 1) for d in degrees]
  _check_pointer(config.freq_reg_end, groups, f' of encodings of {tuple(degrees)} degrees')
  if config.freq_reg_end > config.max_steps:
    warnings.warn(f'Config.freq_reg_end = {config.freq_reg_end} exceeds Config.max_steps = {config.max_steps}: '
                  'the frequency mask never fully opens during training', stacklevel=4)


def _max_end(groups) -> int:
  """The largest T whose pointer fits for every (num, den) of groups."""
  return min(min((2**31 - 1) // num, (2**24 - 1) // den) for num, den in groups)
