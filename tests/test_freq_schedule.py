"""Tests of internal/models/freq_schedule.py against worked examples of the released mask and a literal reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import assert_float32_exact
from internal import runs
from internal.models import freq_schedule

LOW = np.float32(1e-8)
END = 1000


def _expected(length, ones, frac_idx=(), frac=0.):
  """A mask with 1 on indices [0, ones), frac on frac_idx, float32(1e-8) elsewhere."""
  mask = np.full(length, LOW, np.float32)
  mask[:ones] = 1.
  mask[list(frac_idx)] = frac
  return mask


def _reference_released(length, step, end):
  """The released get_freq_reg_mask rule read literally (float64 numpy, slice assignment)."""
  if step >= end:
    return np.ones(length)
  mask = np.zeros(length)
  ptr = min(length / 3 * step / end + 1, length / 3)
  n = int(ptr)
  mask[:3 * n] = 1.
  mask[3 * n:3 * n + 3] = ptr - n
  return np.clip(mask, 1e-8, 1 - 1e-8)


@pytest.mark.parametrize('ratio,length,expected', [
    (0., 99, _expected(99, 3)),
    (0.25, 99, _expected(99, 27, range(27, 30), 0.25)),
    (0.5, 99, _expected(99, 51, range(51, 54), 0.5)),
    (0.75, 99, _expected(99, 75, range(75, 78), 0.75)),
    (1., 99, np.ones(99, np.float32)),
    (0., 27, _expected(27, 3)),
    (0.25, 27, _expected(27, 9, range(9, 12), 0.25)),
    (0.5, 27, _expected(27, 15, range(15, 18), 0.5)),
    (0.75, 27, _expected(27, 21, range(21, 24), 0.75)),
    (1., 27, np.ones(27, np.float32)),
])
def test_released_worked_example(ratio, length, expected):
  mask = freq_schedule.released_mask(length, int(ratio * END), END)
  assert mask.dtype == jnp.float32 and mask.shape == (length,)
  assert_float32_exact(mask, expected)


def test_released_matches_literal_reference():
  for length in (99, 27):
    for step in range(0, 1100, 7):
      assert_float32_exact(freq_schedule.released_mask(length, step, END),
                           _reference_released(length, step, END).astype(np.float32))


def test_released_pointer_is_exact():
  """L = 99, T = 62791, t = 59127: ptr - 1 = 33 t / T = 31 + 4670 / 62791 exactly; group 32 (features
  96..98) gets the float32 rounding of 4670 / 62791 = 0.0743737 (a float32 pointer gave 0.0743713)."""
  mask = np.asarray(freq_schedule.released_mask(99, 59127, 62791))
  ptr = 99 / 3 * 59127 / 62791 + 1  # The released formula in float64.
  assert_float32_exact(mask[96:], np.float32(ptr - int(ptr)))
  assert_float32_exact(mask[96], np.float32(4670 / 62791))
  assert abs(mask[96] - 0.0743737) < 5e-8
  np.testing.assert_array_equal(mask[:96], 1.)
  traced = jax.jit(lambda s: freq_schedule.released_mask(99, s, 62791))(jnp.int32(59127))
  np.testing.assert_array_equal(traced, mask)


def test_pointer_bound_checked():
  with pytest.raises(ValueError, match='Config.freq_reg_end'):
    freq_schedule.released_mask(99, 0, 2**25)


def test_released_ends():
  assert np.all(np.asarray(freq_schedule.released_mask(99, END, END)) == 1.)
  assert np.all(np.asarray(freq_schedule.released_mask(99, int(0.98 * END), END)) == 1.)  # capped ptr
  assert np.all(np.asarray(freq_schedule.released_mask(99, 5 * END, END)) == 1.)  # step > T
  assert np.all(np.asarray(freq_schedule.released_mask(99, 0, 0)) == 1.)  # T = 0
  assert np.all(np.asarray(freq_schedule.released_mask(27, 7, 0)) == 1.)
  np.testing.assert_array_equal(freq_schedule.released_mask(99, 0, 1), _expected(99, 3))  # T = 1
  assert np.all(np.asarray(freq_schedule.released_mask(99, 1, 1)) == 1.)
  # Chunk 32 (cos deg 15) is already fully open below T (ptr capped at 33 from t/T = 32/33).
  assert np.all(np.asarray(freq_schedule.released_mask(99, 970, END)) == 1.)
  assert freq_schedule.released_mask(99, 969, END)[98] < 1.


def _expected_paper(length, ones, fracs, frac):
  """Mask with 1 on index set ones, frac on index set fracs, float32(1e-8) elsewhere."""
  mask = np.full(length, LOW, np.float32)
  mask[list(ones)] = 1.
  mask[list(fracs)] = frac
  return mask


# Hand-written from the contract: G = D + 1 groups, ptr = G t/T + 1; group g = 0 identity, g = k + 1
# holds sin deg k (3 + 3k + c) and cos deg k (3 + 3D + 3k + c).
@pytest.mark.parametrize('ratio,num_degrees,expected', [
    # ptr = 1: identity only.
    (0., 16, _expected_paper(99, range(0, 3), [], 0.)),
    # ptr = 5.25: identity + deg 0..3 (sin 3..14, cos 51..62); deg 4 (sin 15..17, cos 63..65) = 0.25.
    (0.25, 16, _expected_paper(99, [*range(0, 15), *range(51, 63)], [*range(15, 18), *range(63, 66)], 0.25)),
    # ptr = 9.5: identity + deg 0..7 (sin 3..26, cos 51..74); deg 8 (sin 27..29, cos 75..77) = 0.5.
    (0.5, 16, _expected_paper(99, [*range(0, 27), *range(51, 75)], [*range(27, 30), *range(75, 78)], 0.5)),
    # ptr = 13.75: identity + deg 0..11 (sin 3..38, cos 51..86); deg 12 (sin 39..41, cos 87..89) = 0.75.
    (0.75, 16, _expected_paper(99, [*range(0, 39), *range(51, 87)], [*range(39, 42), *range(87, 90)], 0.75)),
    (1., 16, np.ones(99, np.float32)),
    # View (D = 4, G = 5), ptr = 2.25: identity + deg 0 (sin 3..5, cos 15..17); deg 1 (6..8, 18..20) = 0.25.
    (0.25, 4, _expected_paper(27, [*range(0, 6), *range(15, 18)], [*range(6, 9), *range(18, 21)], 0.25)),
    # ptr = 3.5: identity + deg 0, 1 (sin 3..8, cos 15..20); deg 2 (9..11, 21..23) = 0.5.
    (0.5, 4, _expected_paper(27, [*range(0, 9), *range(15, 21)], [*range(9, 12), *range(21, 24)], 0.5)),
])
def test_paper_worked_example(ratio, num_degrees, expected):
  mask = freq_schedule.paper_mask(num_degrees, int(ratio * END), END)
  assert mask.dtype == jnp.float32
  assert_float32_exact(mask, expected)


def test_paper_ends():
  assert np.all(np.asarray(freq_schedule.paper_mask(16, 0, 0)) == 1.)
  assert np.all(np.asarray(freq_schedule.paper_mask(16, 2 * END, END)) == 1.)
  assert np.all(np.asarray(freq_schedule.paper_mask(16, 942, END)) == 1.)  # ptr capped at 17 from t/T = 16/17
  assert freq_schedule.paper_mask(16, 940, END)[98] < 1.
  np.testing.assert_array_equal(freq_schedule.paper_mask(16, 0, 1), _expected(99, 3))
  assert np.all(np.asarray(freq_schedule.paper_mask(16, 1, 1)) == 1.)
  assert freq_schedule.paper_mask(2, 0, END, num_coords=2).shape == (10,)


def test_fixed_ratio_mask():
  np.testing.assert_array_equal(freq_schedule.fixed_ratio_mask(99, 0.5), np.r_[np.ones(49), np.zeros(50)])
  np.testing.assert_array_equal(freq_schedule.fixed_ratio_mask(27, 0.1), np.r_[np.ones(2), np.zeros(25)])
  np.testing.assert_array_equal(freq_schedule.fixed_ratio_mask(27, 1.), np.ones(27))


def test_encoding_masks_dispatch():
  kw = dict(freq_reg=True, freq_reg_end=END, layout='released', max_vis_freq_ratio=0., num_deg_point=16,
            num_deg_view=4)
  assert freq_schedule.encoding_masks(5, **{**kw, 'freq_reg': False}) == (None, None)
  assert freq_schedule.encoding_masks(5, **{**kw, 'freq_reg_end': 0}) == (None, None)
  point, view = freq_schedule.encoding_masks(250, **kw)
  np.testing.assert_array_equal(point, freq_schedule.released_mask(99, 250, END))
  np.testing.assert_array_equal(view, freq_schedule.released_mask(27, 250, END))
  point, view = freq_schedule.encoding_masks(250, **{**kw, 'layout': 'paper'})
  np.testing.assert_array_equal(point, freq_schedule.paper_mask(16, 250, END))
  np.testing.assert_array_equal(view, freq_schedule.paper_mask(4, 250, END))
  for end in (END, 0):  # The fixed visible ratio acts under freq_reg, whatever its end step.
    point, view = freq_schedule.encoding_masks(250, **{**kw, 'freq_reg_end': end, 'max_vis_freq_ratio': 0.5})
    np.testing.assert_array_equal(point, freq_schedule.fixed_ratio_mask(99, 0.5))
    np.testing.assert_array_equal(view, freq_schedule.fixed_ratio_mask(27, 0.5))
  # As released, it does not act without the frequency regularizer.
  assert freq_schedule.encoding_masks(250, **{**kw, 'freq_reg': False, 'max_vis_freq_ratio': 0.5}) == (None, None)
  point, view = freq_schedule.encoding_masks(250, **{**kw, 'num_deg_point': 10, 'num_deg_view': 2})
  assert (point.shape, view.shape) == ((63,), (15,))  # The degrees passed, not defaults, set the lengths.
  with pytest.raises(ValueError, match='Config.freq_mask_layout'):
    freq_schedule.encoding_masks(5, **{**kw, 'layout': 'interleaved'})


def _reference_paper(num_degrees, step, end):
  """Paper layout read literally (float64 numpy): identity is group 0, sin and cos of degree k group k + 1."""
  if step >= end:
    return np.ones(3 + 6 * num_degrees)
  bands = np.repeat(np.arange(1, num_degrees + 1), 3)
  group = np.concatenate([np.zeros(3), bands, bands])
  ptr = (num_degrees + 1) * step / end
  n = int(ptr)
  mask = np.where(group <= n, 1., np.where(group == n + 1, ptr - n, 0.))
  return np.clip(mask, 1e-8, 1 - 1e-8)


@pytest.mark.parametrize('name,fn,reference', [
    ('released', lambda s: freq_schedule.released_mask(99, s, END), lambda s: _reference_released(99, s, END)),
    ('paper', lambda s: freq_schedule.paper_mask(4, s, END), lambda s: _reference_paper(4, s, END)),
    ('encoding_masks', lambda s: freq_schedule.encoding_masks(
        s, freq_reg=True, freq_reg_end=END, layout='released', max_vis_freq_ratio=0., num_deg_point=16,
        num_deg_view=4)[1],
     lambda s: _reference_released(27, s, END)),
])
def test_jit_with_traced_step_compiles_once(name, fn, reference):
  traces = []

  def traced(step):
    traces.append(name)
    return fn(step)

  jitted = jax.jit(traced)
  for step in (0, 1, 250, 333, 500, 999, 1000, 4000):
    np.testing.assert_allclose(jitted(jnp.asarray(step, jnp.int32)), reference(step), rtol=0, atol=4e-6)
  assert len(traces) == 1


def test_too_large_end_is_refused_when_the_config_is_loaded():
  """A T the exact pointer cannot hold is a settings error at load time, before a run directory is written."""
  largest = (2**24 - 1) // 3  # Released layout: 3 features a group, den * T < 2**24.
  def load(end, *bindings):
    return runs.bind_fresh([], [f'Config.freq_reg_end = {end}', f'Config.max_steps = {end}', *bindings])
  with pytest.raises(ValueError, match=rf'Config.freq_reg_end = {largest + 1} is too large .*at most {largest}'):
    load(largest + 1, 'Config.freq_reg = True')
  load(largest, 'Config.freq_reg = True')
  load(largest + 1)  # Without Config.freq_reg the schedule is off and any T is accepted.
