"""Learning-rate and padding schedules against values of the released schedule computed by hand."""

import numpy as np
import pytest

from internal import configs
from internal.training import schedule

REGNERF_LR = dict(lr_init=2e-3, lr_final=2e-5, lr_delay_steps=512, lr_delay_mult=0.01)

DTU3 = [(0, 2.000e-5), (1, 2.607e-5), (100, 6.115e-4), (256, 1.382e-3), (512, 1.896e-3),
        (10000, 7.013e-4), (21972, 2.000e-4), (43945, 2e-5)]
LLFF3 = [(1, 2.6073e-5), (512, 1.9335e-3), (34884, 2.0e-4)]


@pytest.mark.parametrize('max_steps,table', [(43945, DTU3), (69768, LLFF3)])
def test_learning_rate_fixtures(max_steps, table):
  for step, expected in table:
    lr = float(schedule.learning_rate(step, max_steps=max_steps, **REGNERF_LR))
    assert lr == pytest.approx(expected, rel=5e-4), step


def test_learning_rate_extremes_are_finite_and_bounded():
  steps = np.array([0, 1, 43945, 10**7])
  lrs = np.asarray(schedule.learning_rate(steps, max_steps=43945, **REGNERF_LR))
  assert np.all(np.isfinite(lrs))
  assert lrs[-1] == pytest.approx(2e-5, rel=1e-5)  # Clamped past max_steps.
  assert np.all(lrs <= 2e-3)


def test_no_delay_is_pure_log_linear():
  mid = float(schedule.learning_rate(50, 1e-2, 1e-4, 100))
  assert mid == pytest.approx(1e-3, rel=1e-5)


def test_resample_padding_constant_by_default():
  config = configs.Config(max_steps=100)
  assert float(schedule.resample_padding(config, 0)) == pytest.approx(0.01)
  assert float(schedule.resample_padding(config, 100)) == pytest.approx(0.01)
