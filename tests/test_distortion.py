"""COLMAP camera models: the distortion against its formula, undistortion as its inverse, pixel directions."""

import numpy as np
import pytest

from internal.cameras import caster, distortion
from internal.cameras.records import Cameras


def camera_directions(params: np.ndarray, height: int, width: int) -> np.ndarray:
  """[H, W, 3] OpenCV camera-frame directions (z = 1) of the pixel centres of a camera of COLMAP's params [8]."""
  camera = Cameras(np.eye(3, 4)[None], np.eye(3)[None], params[None])
  return caster.camera_directions(camera, caster.image_pixels(0, height, width), opengl=False)

# An OPENCV camera with a phone's distortion: barrel k1, k2 and a little tangential.
OPENCV = np.array([500., 510., 320.5, 240.25, -.12, .03, 1e-3, -5e-4])


def test_models_map_onto_opencv_parameters():
  assert list(distortion.opencv_params('SIMPLE_PINHOLE', [5., 1., 2.])) == [5., 5., 1., 2., 0., 0., 0., 0.]
  assert list(distortion.opencv_params('PINHOLE', [5., 6., 1., 2.])) == [5., 6., 1., 2., 0., 0., 0., 0.]
  assert list(distortion.opencv_params('SIMPLE_RADIAL', [5., 1., 2., .1])) == [5., 5., 1., 2., .1, 0., 0., 0.]
  assert list(distortion.opencv_params('RADIAL', [5., 1., 2., .1, .2])) == [5., 5., 1., 2., .1, .2, 0., 0.]
  with pytest.raises(distortion.UnsupportedCameraError, match="'OPENCV_FISHEYE' is not supported"):
    distortion.opencv_params('OPENCV_FISHEYE', [1.] * 8)


def test_distortion_by_hand():
  """u = 0.2, v = -0.1: r2 = 0.05, radial = k1 r2 + k2 r2^2, plus the tangential terms, written out."""
  k1, k2, p1, p2 = OPENCV[4:]
  u, v, r2 = .2, -.1, .05
  radial = k1 * r2 + k2 * r2 ** 2
  expected_u = u * (1 + radial) + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
  expected_v = v * (1 + radial) + p1 * (r2 + 2 * v * v) + 2 * p2 * u * v
  assert distortion.distort(OPENCV, np.array(u), np.array(v)) == pytest.approx((expected_u, expected_v), abs=1e-15)


@pytest.mark.parametrize('params', [OPENCV, distortion.opencv_params('RADIAL', [400., 200., 150., .08, -.02]),
                                    distortion.opencv_params('SIMPLE_RADIAL', [400., 200., 150., -.2])])
def test_undistort_inverts_distort_over_the_image(params):
  rng = np.random.default_rng(0)
  u, v = rng.uniform(-.7, .7, 5000), rng.uniform(-.55, .55, 5000)  # A 70-degree field of view.
  back = distortion.undistort(params, *distortion.distort(params, u, v))
  np.testing.assert_allclose(back, (u, v), atol=1e-12)


def test_pixel_directions_project_back_onto_their_pixels():
  """Each direction (u, v, 1), distorted and mapped by the intrinsics, lands on its pixel centre."""
  directions = camera_directions(OPENCV, 48, 64)
  ud, vd = distortion.distort(OPENCV, directions[..., 0], directions[..., 1])
  x, y = OPENCV[0] * ud + OPENCV[2], OPENCV[1] * vd + OPENCV[3]
  np.testing.assert_allclose(x, np.broadcast_to(np.arange(64) + .5, (48, 64)), atol=1e-9)
  np.testing.assert_allclose(y, np.broadcast_to((np.arange(48) + .5)[:, None], (48, 64)), atol=1e-9)
  assert (directions[..., 2] == 1.).all()


def test_pinhole_directions_are_the_inverse_intrinsics():
  params = distortion.opencv_params('PINHOLE', [100., 90., 30., 20.])
  directions = camera_directions(params, 2, 3)
  assert directions[1, 2] == pytest.approx([(2.5 - 30.) / 100., (1.5 - 20.) / 90., 1.])


def test_downscaling_keeps_pixel_centres_on_the_same_rays():
  """A pixel of the image downsampled by 4 covers 4 x 4 pixels: its centre's ray is their centre's ray."""
  coarse = camera_directions(distortion.scaled(OPENCV, 4.), 12, 16)
  u, v = distortion.pixel_to_normalized(OPENCV, np.array(4 * 3 + 2.), np.array(4 * 5 + 2.))
  assert coarse[5, 3, :2] == pytest.approx([u, v], abs=1e-12)
