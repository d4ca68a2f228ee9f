"""COLMAP sparse models: the shared cup capture against its independent poses_bounds.npy, binary and text round
trips, quaternions, and the errors of damaged models."""

import filecmp
import os

import numpy as np
import pytest

from internal.cameras import algebra
from internal.datasets import colmap_model as cm
from tests.conftest import SHARED_DATA

CUP = SHARED_DATA / 'colmap' / 'cup'
needs_cup = pytest.mark.skipif(not (CUP / 'sparse' / '0').is_dir(),
                               reason=f'the shared COLMAP capture {CUP} is absent (a user clone has no ../shared)')


@pytest.fixture(name='cup', scope='module')
def fixture_cup():
  return cm.read_model(str(CUP / 'sparse' / '0'))


def _tiny_model():
  """Two cameras (SIMPLE_RADIAL, OPENCV), two images (one with no 2D points), two 3D points."""
  cameras = {1: cm.Camera(1, 'SIMPLE_RADIAL', 40, 30, np.array([35., 20., 15., .01])),
             7: cm.Camera(7, 'OPENCV', 40, 30, np.array([35., 36., 20.5, 14.5, .02, -.01, .001, -.002]))}
  points2d = np.array([(1.5, 2.25, 3), (10., 11., -1)], cm.POINT2D)
  images = {2: cm.Image(2, np.array([1., 0., 0., 0.]), np.array([0., 0., 4.]), 1, 'a b.png', points2d),
            5: cm.Image(5, algebra.rotation_to_quaternion(np.diag([1., -1., -1.])), np.array([.1, .2, 3.]), 7, 'c.png',
                        np.zeros(0, cm.POINT2D))}
  points = {3: cm.Point3D(3, np.array([.1, -.2, .3]), np.array([1, 2, 250], np.uint8), .5,
                          np.array([(2, 0), (5, 4)], cm.TRACK)),
            9: cm.Point3D(9, np.array([0., 0., 1.]), np.array([0, 0, 0], np.uint8), 0., np.array([(2, 1)], cm.TRACK))}
  return cm.Model(cameras, images, points)


def _assert_same(a: cm.Model, b: cm.Model):
  assert a.cameras.keys() == b.cameras.keys() and a.images.keys() == b.images.keys()
  for i, camera in a.cameras.items():
    other = b.cameras[i]
    assert (camera.model, camera.width, camera.height) == (other.model, other.width, other.height)
    np.testing.assert_array_equal(camera.params, other.params)
  for i, image in a.images.items():
    other = b.images[i]
    assert (image.name, image.camera_id) == (other.name, other.camera_id)
    for field in ('qvec', 'tvec', 'points2d'):
      np.testing.assert_array_equal(getattr(image, field), getattr(other, field))
  assert a.points.keys() == b.points.keys()
  for i, point in a.points.items():
    other = b.points[i]
    assert point.error == other.error
    for field in ('xyz', 'rgb', 'track'):
      np.testing.assert_array_equal(getattr(point, field), getattr(other, field))


@needs_cup
def test_cup_poses_equal_the_independent_poses_bounds(cup):
  """poses_bounds.npy (LLFF's imgs2poses, rows in name order): [down, right, back] camera-to-world and centre."""
  rows = np.load(CUP / 'poses_bounds.npy')
  images = sorted(cup.images.values(), key=lambda i: i.name)
  assert len(images) == len(rows) == 77
  for image, row in zip(images, rows):
    rotation = algebra.quaternion_to_rotation(image.qvec).T  # Columns: camera right, down, forward in the world.
    expected = row[:15].reshape(3, 5)
    np.testing.assert_allclose(rotation[:, [1, 0]], expected[:, :2], atol=1e-12)
    np.testing.assert_allclose(-rotation[:, 2], expected[:, 2], atol=1e-12)
    np.testing.assert_allclose(cm.camera_center(image), expected[:, 3], atol=1e-12)
  camera = cup.cameras[images[0].camera_id]
  assert (camera.model, camera.height, camera.width) == ('SIMPLE_PINHOLE', 600, 800)
  np.testing.assert_allclose(camera.params[0], rows[0, 14], rtol=1e-14)  # The file repeats the first focal.


@needs_cup
def test_cup_depth_bounds_equal_the_independent_ones(cup):
  rows = np.load(CUP / 'poses_bounds.npy')
  bounds = cm.depth_bounds(cup)
  ordered = [bounds[i.image_id] for i in sorted(cup.images.values(), key=lambda i: i.name)]
  np.testing.assert_allclose(ordered, rows[:, 15:], rtol=1e-12)


@needs_cup
def test_cup_binary_written_back_is_byte_identical(cup, tmp_path):
  cm.write_binary(cup, str(tmp_path))
  for name in cm.FILES:
    assert filecmp.cmp(tmp_path / f'{name}.bin', CUP / 'sparse' / '0' / f'{name}.bin', shallow=False)


@needs_cup
def test_cup_text_and_binary_readers_agree(cup, tmp_path):
  cm.write_text(cup, str(tmp_path))
  assert cm.model_format(str(tmp_path)) == '.txt'
  _assert_same(cup, cm.read_model(str(tmp_path)))


@pytest.mark.parametrize('write', [cm.write_binary, cm.write_text])
def test_round_trip_of_every_field(write, tmp_path):
  model = _tiny_model()
  write(model, str(tmp_path))
  _assert_same(model, cm.read_model(str(tmp_path)))


def test_quaternions_against_rodrigues():
  """R(q) of q = (cos a/2, sin a/2 axis) equals Rodrigues' rotation by a about axis; and back."""
  rng = np.random.default_rng(0)
  for _ in range(20):
    axis, angle = rng.normal(size=3), rng.uniform(0, np.pi)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rodrigues = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    qvec = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
    np.testing.assert_allclose(algebra.quaternion_to_rotation(qvec), rodrigues, atol=1e-12)
    np.testing.assert_allclose(algebra.rotation_to_quaternion(rodrigues), qvec, atol=1e-12)


def test_truncated_file_names_it(tmp_path):
  cm.write_binary(_tiny_model(), str(tmp_path))
  path = tmp_path / 'images.bin'
  path.write_bytes(path.read_bytes()[:-5])
  with pytest.raises(cm.ColmapError, match=f"{path}.*ends early"):
    cm.read_model(str(tmp_path))


def test_unknown_model_id_and_missing_camera_are_named(tmp_path):
  model = _tiny_model()
  cm.write_binary(model, str(tmp_path))
  data = bytearray((tmp_path / 'cameras.bin').read_bytes())
  data[12:16] = (42).to_bytes(4, 'little')  # The first camera's model id.
  (tmp_path / 'cameras.bin').write_bytes(bytes(data))
  with pytest.raises(cm.ColmapError, match='camera 1 has model id 42'):
    cm.read_model(str(tmp_path))
  del model.cameras[7]
  cm.write_text(model, str(tmp_path / 'text'))
  with pytest.raises(cm.ColmapError, match="image 'c.png' uses camera 7"):
    cm.read_model(str(tmp_path / 'text'))


def test_a_folder_without_a_model_says_what_it_expected(tmp_path):
  (tmp_path / 'cameras.bin').write_bytes(b'')
  with pytest.raises(cm.ColmapError, match=r"expected cameras, images and points3D as \.bin or \.txt; found "
                                           r"\['cameras\.bin'\]"):
    cm.read_model(str(tmp_path))
  with pytest.raises(cm.ColmapError, match='does not exist'):
    cm.read_model(os.path.join(tmp_path, 'nothing'))
