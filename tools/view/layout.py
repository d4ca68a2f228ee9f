"""Two runs from one camera: a frame cut into column ranges, each rendered by one run, then put back together.

'split': the columns left of the slider from the first run, the rest from the second; 'side by side': each run
shows the centre half of the view, the first on the left, so that the frame keeps its size and aspect. A one-pixel
white divider marks where the second run begins. Each run renders only its columns, so that a comparison costs what
one run's frame costs.
"""

import numpy as np

LAYOUTS = ('split', 'side by side')
DIVIDER = 1.  # The divider's colour (white), in every channel.


def split_column(width: int, fraction: float) -> int:
  """The first column of the second run in a split at fraction (0: left edge, 1: right edge) of width columns."""
  return int(round(min(max(fraction, 0.), 1.) * width))


def panels(layout: str, width: int, fraction: float = .5) -> list:
  """[(run index, first column, end column)] of the view's columns that each panel shows, left to right; layout
  None: the first run alone."""
  if layout is None:
    return [(0, 0, width)]
  if layout == 'split':
    cut = split_column(width, fraction)
    return [(run, start, end) for run, start, end in ((0, 0, cut), (1, cut, width)) if end > start]
  if layout != 'side by side':
    raise ValueError(f'layout {layout!r}: expected one of {list(LAYOUTS)}')
  left = width // 2
  right = width - left
  return [(0, (width - left) // 2, (width - left) // 2 + left), (1, (width - right) // 2, (width - right) // 2 + right)]


def compose(images, layout: str) -> np.ndarray:
  """The frame [H, W, 3] of the panels' images [H, w_i, 3] side by side; with a layout, the second panel's first
  column is the divider."""
  frame = np.concatenate(images, axis=1)
  if layout is not None and len(images) == 2 and images[0].shape[1]:
    frame[:, images[0].shape[1]] = DIVIDER
  return frame
