"""The one ray caster: Rays through pixels of Cameras in a RaySpace, as numpy arrays at load time (float64, stored
as float32) or jax.numpy ones inside the step (float32).

A pixel (x, y) of view v is cast through (x, y) + RaySpace.pixel_offset of camera v: a camera-frame direction with
|z| = 1 (its pixtocam, or COLMAP's distortion inverted, distortion.py), turned into the world by the camera's
rotation, from its centre. mip-NeRF's radius of a ray is 2/sqrt(12) times a distance to its neighbours, cast in the
same call: between the world directions of the pixel and the one below (the next row) for world rays, the mean of
that distance and the one to the next column between NDC origins for NDC rays. On an image's last row or column the
second-to-last distance serves again, as the released code's images (RaySpace.released_edges; RegNeRF's patches take
the next pixel's everywhere). The space then maps the rays: DTU's origins onto their world plane (from the float32 rays,
as its loader always did), LLFF's NDC map.
"""

import numpy as np

from internal.cameras import distortion
from internal.cameras.records import Cameras, Pixels, RaySpace
from internal.rays import Rays

OPENGL_FLIP = np.array([1., -1., -1.])  # OpenCV camera axes -> OpenGL (x right, y up, looking down -z).
NDC_NEAR_FAR = (0., 1.)  # LLFF's NDC rays span t in [0, 1] whatever Config.near/far say.
NDC_BOX = ((-1., -1., -1.), (1., 1., .99))  # The space NDC rays cross (z = 1 is infinitely far): its region to mesh.
ROW, COLUMN = 0, 1  # The image axes of neighbouring pixels.


def _real(xp):
  """The float type of arrays of module xp: float64 for numpy, float32 for jax.numpy (x64 off)."""
  return np.float64 if xp is np else np.float32


def mat_vec(matrix, x, xp=np):
  """matrix [...,M,3] applied to every vector of x [...,3] -> [...,M] (broadcast)."""
  return xp.einsum('...ij,...j->...i', matrix, x)


def norm(x, xp=np):
  """Euclidean norm over the last axis of x [...,3] -> [...]."""
  return xp.sqrt(xp.einsum('...i,...i->...', x, x))


def image_pixels(view: int, height: int, width: int) -> Pixels:
  """Pixels [H,W] of every pixel of one view's image (the view a scalar that broadcasts)."""
  y, x = np.meshgrid(np.arange(height), np.arange(width), indexing='ij')
  return Pixels(np.asarray(view), x, y)


def camera_directions(cameras: Cameras, pixels: Pixels, opengl: bool, offset=(.5, .5), xp=np):
  """[...,3] camera-frame directions through pixels + offset: the pixtocam's, or through the distortion's inverse
  where cameras have one; |z| = 1 (+1 OpenCV, -1 OpenGL)."""
  x = xp.asarray(pixels.x, _real(xp)) + offset[0]
  y = xp.asarray(pixels.y, _real(xp)) + offset[1]
  flip = xp.asarray(OPENGL_FLIP if opengl else np.ones(3), _real(xp))
  if cameras.distortion is not None:
    u, v = distortion.pixel_to_normalized(xp.asarray(cameras.distortion, _real(xp))[pixels.view], x, y, xp)
    return xp.stack([u, v, xp.ones_like(u)], -1) * flip
  mat = xp.asarray(cameras.pixtocams, _real(xp))[pixels.view] * flip[:, None]
  return x[..., None] * mat[..., :, 0] + y[..., None] * mat[..., :, 1] + mat[..., :, 2]


def world_directions(cameras: Cameras, pixels: Pixels, cam_dirs, xp=np):
  """cam_dirs [...,3] of the cameras of pixels turned into the world."""
  return mat_vec(xp.asarray(cameras.camtoworlds, _real(xp))[pixels.view][..., :3, :3], cam_dirs, xp)


def directions(cameras: Cameras, pixels: Pixels, space: RaySpace, xp=np):
  """[...,3] world directions of the rays through pixels (not unit length: camera-frame |z| = 1)."""
  offset = (space.pixel_offset, space.pixel_offset)
  return world_directions(cameras, pixels, camera_directions(cameras, pixels, space.opengl, offset, xp), xp)


def _pair(index, length: int, released: bool, xp):
  """[...,2] positions along an axis of the given length whose distance sets index's radius: (i, i + 1), and with
  released edges for the last position the pair of the second-to-last distance."""
  first = xp.where(index < length - 1, index, max(length - 3, 0)) if released else index
  return xp.stack([first, first + 1], -1)


def neighbour_directions(cameras: Cameras, pixels: Pixels, space: RaySpace, axis: int, xp=np):
  """[...,2,3] world directions of the neighbouring pixels along axis (ROW: rows, COLUMN: columns) whose distance
  sets the radius of each pixel's ray."""
  view, x, y = pixels
  if np.ndim(view):  # A view per pixel: the same one at both ends of its pair.
    view, x, y = xp.broadcast_arrays(xp.asarray(view), xp.asarray(x), xp.asarray(y))
    view = xp.stack([view, view], -1)
  x, y = xp.broadcast_arrays(xp.asarray(x), xp.asarray(y))
  if axis == ROW:
    ends = Pixels(view, xp.stack([x, x], -1), _pair(y, space.height, space.released_edges, xp))
  else:
    ends = Pixels(view, _pair(x, space.width, space.released_edges, xp), xp.stack([y, y], -1))
  return directions(cameras, ends, space, xp)


def shift_origins(origins, directions_, plane_z: float):
  """Moves origins [...,3] along directions [...,3] onto the world plane z = plane_z."""
  t = (plane_z - origins[..., 2:3]) / directions_[..., 2:3]
  return origins + t * directions_


def convert_to_ndc(origins, directions_, focal: float, height: int, width: int, near: float = 1., xp=np) -> tuple:
  """Forward-facing NDC: (origins [...,3] on z = -1, directions [...,3]) from world rays looking down -z."""
  origins = shift_origins(origins, directions_, -near)
  ox, oy, oz = xp.moveaxis(origins, -1, 0)
  dx, dy, dz = xp.moveaxis(directions_, -1, 0)
  ndc_o = xp.stack([-2. * focal / width * ox / oz, -2. * focal / height * oy / oz, 1. + 2. * near / oz], -1)
  ndc_far = xp.stack([-2. * focal / width * dx / dz, -2. * focal / height * dy / dz, xp.ones_like(dz)], -1)
  return ndc_o, ndc_far - ndc_o


def _gap(ends, xp):
  """[...] the distance between the two ends [...,2,3]."""
  return norm(ends[..., 1, :] - ends[..., 0, :], xp)


def ndc_fields(centres, dirs, row_dirs, column_dirs, space: RaySpace, xp=np) -> tuple:
  """(origins, directions, viewdirs, radii) of NDC rays from the cameras' centres [...,3] along world directions
  dirs [...,3], their radii from the NDC origins of the neighbours' world directions [...,2,3] along rows and
  columns."""
  ndc = lambda o, d: convert_to_ndc(o, d, space.ndc_focal, space.height, space.width, xp=xp)
  origins, ndc_dirs = ndc(centres, dirs)
  ends = lambda pair: ndc(centres[..., None, :], pair)[0]
  radii = (.5 * (_gap(ends(row_dirs), xp) + _gap(ends(column_dirs), xp)))[..., None] * 2. / np.sqrt(12.)
  viewdirs = dirs / norm(dirs, xp)[..., None] if space.unit_viewdirs else dirs
  return origins, ndc_dirs, viewdirs, radii


def pack(origins, directions_, viewdirs, radii, near: float, far: float, xp=np) -> Rays:
  """Rays of float32 arrays [...,3]/[...,1] with lossmult 1 and constant near/far."""
  ones = xp.ones(radii.shape, np.float32)
  f32 = lambda x: xp.asarray(x, np.float32)
  return Rays(f32(origins), f32(directions_), f32(viewdirs), f32(radii), ones, ones * np.float32(near),
              ones * np.float32(far))


def cast(cameras: Cameras, pixels: Pixels, space: RaySpace, xp=np) -> Rays:
  """Rays [...] (float32) through pixels [...] of cameras in space (module docstring)."""
  dirs = directions(cameras, pixels, space, xp)
  centres = xp.broadcast_to(xp.asarray(cameras.camtoworlds, _real(xp))[pixels.view][..., :3, 3], dirs.shape)
  rows = neighbour_directions(cameras, pixels, space, ROW, xp)
  if space.ndc_focal:
    columns = neighbour_directions(cameras, pixels, space, COLUMN, xp)
    return pack(*ndc_fields(centres, dirs, rows, columns, space, xp), space.near, space.far, xp)
  radii = _gap(rows, xp)[..., None] * 2. / np.sqrt(12.)
  rays = pack(centres, dirs, dirs / norm(dirs, xp)[..., None], radii, space.near, space.far, xp)
  if space.plane_z is None:
    return rays
  real = lambda x: xp.asarray(x, _real(xp))
  return rays._replace(origins=xp.asarray(shift_origins(real(rays.origins), real(rays.directions), space.plane_z),
                                          np.float32))


def image_rays(cameras: Cameras, space: RaySpace) -> Rays:
  """Rays [N,H,W,...] of every pixel of the N cameras' images (numpy; one image at a time)."""
  count = len(cameras.camtoworlds)
  return stack_rays((cast(cameras, image_pixels(i, space.height, space.width), space) for i in range(count)), count)


def stack_rays(rays_iter, count: int) -> Rays:
  """Stacks count Rays [H,W,...] from an iterator into preallocated Rays [N,H,W,...]."""
  out = None
  for i, rays in enumerate(rays_iter):
    if out is None:
      out = Rays(*[np.empty((count,) + x.shape, np.float32) for x in rays])
    for dst, src in zip(out, rays):
      dst[i] = src
  return out
