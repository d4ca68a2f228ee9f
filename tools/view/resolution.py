"""The viewer's frame sizes: the full size when the camera rests, and while it moves a smaller one, chosen so that a
frame renders within a time budget at the speed the last frames measured (or a fixed fraction of the full size).
"""

import math

# While the camera moves: at most this many seconds a frame (5 frames a second, interactive enough to steer by), and
# never fewer rows than MIN_ROWS (a smaller picture says nothing; the full size when that is smaller).
FRAME_BUDGET = .2
MIN_ROWS = 12
# The moving-size choices of the viewer's panel: 'auto' follows the budget, the others are fractions of the full size.
MOVING_CHOICES = {'auto': None, '1/8': 1 / 8, '1/4': 1 / 4, '1/2': 1 / 2, 'full': 1.}
SPEED_MEMORY = .5  # Weight of the newest frame in the running seconds-per-ray estimate.
FIRST_FRACTION = 1 / 4  # 'auto' before any speed is known: this fraction of the full size.


def frame_width(height: int, aspect: float) -> int:
  """Columns of a frame of height rows at aspect (width / height): the nearest whole number, at least 1."""
  return max(1, int(round(height * aspect)))


def budget_rows(seconds_per_ray: float, aspect: float, budget: float = FRAME_BUDGET) -> int:
  """The most rows of a frame at aspect that renders within budget seconds at seconds_per_ray > 0 (>= 1)."""
  return max(1, int(math.sqrt(budget / seconds_per_ray / max(aspect, 1e-6))))


def moving_rows(choice: str, full_rows: int, seconds_per_ray: float, aspect: float) -> int:
  """Rows of a frame while the camera moves: MOVING_CHOICES[choice] of full_rows, or ('auto') the most that
  budget_rows allows (FIRST_FRACTION before any speed is known); at least MIN_ROWS (or full_rows when that is
  smaller), at most full_rows."""
  fraction = MOVING_CHOICES[choice]
  if fraction is None and seconds_per_ray <= 0:
    fraction = FIRST_FRACTION
  rows = budget_rows(seconds_per_ray, aspect) if fraction is None else int(round(full_rows * fraction))
  return max(min(MIN_ROWS, full_rows), min(rows, full_rows))


def updated_speed(previous: float, seconds: float, rays: int) -> float:
  """The running seconds-per-ray estimate after a frame of rays took seconds (previous <= 0: none yet)."""
  speed = seconds / max(rays, 1)
  return speed if previous <= 0 else (1. - SPEED_MEMORY) * previous + SPEED_MEMORY * speed
