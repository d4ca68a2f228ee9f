"""Cameras as data: a set of cameras, the pixels rays go through, and the RaySpace that says how rays follow from both.

A loader sets a scene's RaySpace, since it knows it (the camera axes, the pixel offset, near and far, DTU's origin
plane, LLFF's NDC focal length); a Dataset carries its cameras and its space, so that whatever makes rays again
(camera noise and refinement, RegNeRF's patches, the depth priors, camera evaluation) makes them as the loader did.
"""

import dataclasses
from typing import Any, NamedTuple, Optional


class Cameras(NamedTuple):
  """N cameras: numpy arrays at load time, jax arrays inside the step (a pytree)."""
  camtoworlds: Any        # [N,3,4] rotation (the camera's axes in the world) and centre.
  pixtocams: Any          # [N,3,3] inverse intrinsics at the image size.
  distortion: Any = None  # [N,8] COLMAP's (fx, fy, cx, cy, k1, k2, p1, p2) at the image size, or None: pinholes.


class Pixels(NamedTuple):
  """Integer pixel positions [...]: the view (an index into Cameras; it broadcasts against x and y), the column x
  and the row y (a pytree)."""
  view: Any
  x: Any
  y: Any


@dataclasses.dataclass(frozen=True)
class RaySpace:
  """How the rays of a scene follow from its cameras (hashable: a static part of the step)."""
  opengl: bool               # Camera axes: OpenGL (x right, y up, looking down -z: LLFF, Blender) or OpenCV (DTU,
                             # captures: x right, y down, looking down +z).
  near: float                # Every ray's near and far bounds.
  far: float
  height: int                # The image size (NDC's map and the released edge rule read it).
  width: int
  pixel_offset: float = .5   # Rays go through (x, y) + pixel_offset: .5 for the pixel centres.
  plane_z: Optional[float] = None  # DTU: origins moved onto the world plane z = plane_z.
  ndc_focal: float = 0.      # > 0: LLFF's NDC rays of this focal length (pixels).
  unit_viewdirs: bool = False  # NDC rays: unit viewdirs (RegNeRF's patches), else the world directions (LLFF's,
                               # as released). World rays always have unit viewdirs.
  released_edges: bool = True  # Radii: on the last row or column the second-to-last distance, as the released
                               # code's images; False: the next pixel's everywhere (RegNeRF's patches).
