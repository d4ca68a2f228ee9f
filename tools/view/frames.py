"""One frame of the viewer: the browser's camera at a size, its rays per panel rendered by the panel's run, shown as
colour, depth or accumulation (render.py's pictures: internal/evaluation/vis.py), the panels put together.

A frame renders in bands of rows, and a newer request stops it between two bands (Cancelled): a full-size frame of
a large model takes seconds, and the camera may have moved on.
"""

import dataclasses
from typing import Optional

import numpy as np

from internal.evaluation import vis
from internal.rays import Rays
from tools.view import cameras, layout, resolution

OUTPUTS = ('colour', 'depth', 'accumulation')
BAND_RAYS = 16384  # Rays rendered between two checks for a newer request.


class Cancelled(Exception):
  """A newer request overtook the frame being rendered."""


@dataclasses.dataclass(frozen=True)
class View:
  """A browser's camera: unit quaternion wxyz [4] and position [3] of camera to world (OpenCV axes), vertical field
  of view fov (radians), aspect (width / height)."""
  wxyz: tuple
  position: tuple
  fov: float
  aspect: float


@dataclasses.dataclass(frozen=True)
class Options:
  """What the viewer's panel chose: the output shown, the size while moving (resolution.MOVING_CHOICES), the full
  size's rows, and for two runs the layout (layout.LAYOUTS) and the split's fraction."""
  output: str = 'colour'
  moving: str = 'auto'
  full_rows: int = 64
  layout: Optional[str] = None
  fraction: float = .5


def render_panel(run, rays: Rays, cancelled) -> dict:
  """run.render of rays [H, w, ...] band by band; Cancelled when cancelled() turns true between two bands."""
  height, width = rays.origins.shape[:2]
  step = max(1, BAND_RAYS // max(width, 1))
  parts = []
  for row in range(0, height, step):
    if cancelled():
      raise Cancelled()
    parts.append(run.render(Rays(*[x[row:row + step] for x in rays])))
  return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def pictures(renderings: list, output: str) -> list:
  """The panels' images [H, w, 3] in [0, 1] of their renderings: colour, depth (one -log-depth range over all
  panels, so that they compare) or accumulation."""
  if output == 'colour':
    return [np.asarray(r['rgb'], np.float64) for r in renderings]
  if output == 'accumulation':
    return [vis.colorize_opacity(r['acc']) for r in renderings]
  if output != 'depth':
    raise ValueError(f'output {output!r}: expected one of {list(OUTPUTS)}')
  depth_range = vis.depth_range(np.concatenate([r['distance_mean'].ravel() for r in renderings]))
  return [vis.colorize_depth(r['distance_mean'], depth_range) for r in renderings]


def render_frame(runs: list, view: View, rows: int, options: Options, cancelled=lambda: False) -> tuple:
  """(uint8 frame [rows, W, 3], rays rendered) of view at rows x resolution.frame_width(rows, aspect): one panel of
  runs[0], or with two runs the panels of options.layout."""
  width = resolution.frame_width(rows, view.aspect)
  c2w, pixtocam = cameras.view_camera(view.wxyz, view.position, view.fov, rows, width)
  chosen = options.layout if len(runs) > 1 else None
  renderings = []
  for index, start, end in layout.panels(chosen, width, options.fraction):
    rays = cameras.camera_rays(c2w, pixtocam, rows, width, runs[index].space)
    renderings.append(render_panel(runs[index], Rays(*[x[:, start:end] for x in rays]), cancelled))
  frame = layout.compose(pictures(renderings, options.output), chosen)
  return vis.to_uint8(frame), rows * width
