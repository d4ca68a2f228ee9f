"""cameras.png: the recovered cameras and sparse points from above and from the side, in the loader's frame.

Cameras are dots coloured by their place in the capture order (name order: the order photos were taken in), joined
by a thin line in that order, each with a short stroke along its viewing direction; the default training views are
green squares and the test views orange triangles, named. A capture taken in one sweep should show a smooth line;
a line that zigzags or folds back over itself is what a wrong reconstruction looks like.
"""

from typing import Dict, List

import matplotlib.figure
import numpy as np

MAX_POINTS = 20000
POINT_PERCENTILES = (2., 98.)  # Points outside this box (per axis) are left out of the picture: stray matches.
STROKE = .15  # Viewing-direction stroke, in the loader's frame (inward captures: the median camera is 1 away).


def _points_shown(points: np.ndarray, colours: np.ndarray) -> tuple:
  """The points [P, 3] (and colours [P, 3]) inside the percentile box, at most MAX_POINTS of them, evenly taken."""
  if not len(points):
    return points, colours
  low, high = np.percentile(points, POINT_PERCENTILES, axis=0)
  keep = np.all((points >= low) & (points <= high), axis=1)
  points, colours = points[keep], colours[keep]
  step = max(1, len(points) // MAX_POINTS)
  return points[::step], colours[::step]


def view_axes(c2w: np.ndarray, forward: bool) -> Dict[str, np.ndarray]:
  """{'top', 'side'}: [2, 3] projections of the world onto each panel's (horizontal, vertical) axes. Up is +z
  for inward captures, +y for forward ones (LLFF's frame); the side view looks along the cameras' widest spread,
  so that its horizontal axis runs from the cameras into the scene."""
  up = np.array([0., 1., 0.]) if forward else np.array([0., 0., 1.])
  first, second = (np.array([1., 0., 0.]), np.array([0., 0., -1.])) if forward else np.eye(3)[:2]
  centres = c2w[:, :, 3] - c2w[:, :, 3].mean(0)
  flat = np.stack([centres @ first, centres @ second], -1)
  spread = np.linalg.svd(flat, full_matrices=False)[2][0] if len(flat) > 1 else np.array([1., 0.])
  depth = -spread[1] * first + spread[0] * second
  depth *= np.sign(c2w[:, :, 2].mean(0) @ depth) or 1.  # Pointing where the cameras look.
  return {'top': np.stack([first, second]), 'side': np.stack([depth, up])}


def _panel(ax, projection, c2w, points, colours, order, views, names):
  """One panel: points, the capture-order path, cameras with viewing strokes, the chosen views named."""
  centres, looks = c2w[:, :, 3] @ projection.T, c2w[:, :, 2] @ projection.T
  ax.scatter(*(points @ projection.T).T, c=colours, s=1, linewidths=0)
  ax.plot(*centres[order].T, color='0.6', lw=.6, zorder=2)
  for centre, look in zip(centres, looks):
    ax.plot(*np.stack([centre, centre + STROKE * look]).T, color='0.3', lw=.6, zorder=3)
  rank = np.empty(len(order))
  rank[order] = np.arange(len(order))
  dots = ax.scatter(*centres.T, c=rank, cmap='viridis', s=14, zorder=4)
  for split, (marker, colour) in {'train': ('s', 'tab:green'), 'test': ('^', 'tab:orange')}.items():
    ids = views[split]
    ax.scatter(*centres[ids].T, marker=marker, s=70, facecolors='none', edgecolors=colour, lw=1.5, zorder=5,
               label=f'{split} views ({len(ids)})')
    for i in ids:
      ax.annotate(names[i], centres[i], fontsize=6, color=colour, xytext=(3, 3), textcoords='offset points')
  ax.set_aspect('equal', adjustable='datalim')
  return dots


def draw(path: str, c2w: np.ndarray, forward: bool, points: np.ndarray, colours: np.ndarray,
         names: List[str], order: List[int], views: Dict[str, List[int]], title: str) -> None:
  """Writes the picture of cameras c2w [N, 3, 4] (loader frame; names [N]), points [P, 3] with colours [P, 3] in
  [0, 1], the capture order (indices) and the views {'train', 'test'} (indices) to path."""
  points, colours = _points_shown(points, colours)
  fig = matplotlib.figure.Figure(figsize=(13, 6.5))
  axes = fig.subplots(1, 2)
  for ax, (label, projection) in zip(axes, view_axes(c2w, forward).items()):
    dots = _panel(ax, projection, c2w, points, colours, order, views, names)
    ax.set_title(f'from {"above" if label == "top" else "the side"}', fontsize=10)
  axes[0].legend(loc='upper right', fontsize=8)
  fig.colorbar(dots, ax=list(axes), shrink=.7, label='place in the capture order (file names)')
  fig.suptitle(title, fontsize=11)
  fig.savefig(path, dpi=110)
