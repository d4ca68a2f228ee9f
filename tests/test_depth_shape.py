"""tools.depth_shape: the correlation, median ratio and the error left after the best scale and shift, by hand."""

import numpy as np
import pytest

from tools import depth_shape


def test_an_affine_map_of_the_truth_has_correlation_one_and_no_error_after_the_fit():
  exact = np.array([[2., 3., 0.], [4., 6., 5.]])  # 0: a pixel that hits nothing, left out.
  shape = depth_shape.view_shape(.5 * exact + 1., exact)
  assert shape['corr'] == pytest.approx(1.) and shape['mae_affine'] == pytest.approx(0., abs=1e-12)
  hit = exact[exact > 0]
  assert shape['mae'] == pytest.approx(np.abs(.5 * hit + 1. - hit).mean())
  assert shape['median_ratio'] == pytest.approx((.5 * 4. + 1.) / 4.)


def test_a_reversed_depth_has_correlation_minus_one_and_the_fit_removes_nothing_of_a_constant():
  exact = np.array([[1., 2., 3., 4.]])
  assert depth_shape.view_shape(5. - exact, exact)['corr'] == pytest.approx(-1.)
  flat = depth_shape.view_shape(np.array([[1., 1., 1., 3.]]), exact)  # The fit is the best line, by hand.
  x, y = np.array([1., 1., 1., 3.]), exact[0]
  a, b = np.polyfit(x, y, 1)
  assert flat['mae_affine'] == pytest.approx(np.abs(a * x + b - y).mean())
