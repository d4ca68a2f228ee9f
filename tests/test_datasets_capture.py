"""The capture loader (internal/datasets/capture.py): a COLMAP model written from the generated scene's exact
cameras gives its rays back; the shared cup capture's rays pass through its own sparse points; the view rule;
explicit view ids for every dataset; the errors of bad captures."""

import dataclasses
import json
import os
import re

import numpy as np
from PIL import Image
import pytest

from internal import config_loader
from internal.configs import Config
from internal.cameras import algebra, caster, distortion
from internal.datasets import DatasetError, colmap_model as cm, load_dataset, loader
from internal.datasets import capture as capture_loader
from internal.datasets import random_poses
from internal.datasets.batching import make_batcher
from internal.evaluation import results
from internal.run import run_dir
from tests.conftest import SHARED_DATA
from tools import mesh as mesh_tool

CUP = SHARED_DATA / 'colmap' / 'cup'
needs_cup = pytest.mark.skipif(not (CUP / 'sparse' / '0').is_dir(),
                               reason=f'the shared COLMAP capture {CUP} is absent (a user clone has no ../shared)')


def _umeyama(source: np.ndarray, target: np.ndarray):
  """(scale, rotation [3,3], translation [3]) of the similarity taking points source [N,3] onto target [N,3]."""
  mu_s, mu_t = source.mean(0), target.mean(0)
  u, sigma, vt = np.linalg.svd((target - mu_t).T @ (source - mu_s))
  sign = np.diag([1., 1., np.sign(np.linalg.det(u @ vt))])
  rotation = u @ sign @ vt
  scale = np.trace(np.diag(sigma) @ sign) / ((source - mu_s) ** 2).sum()
  return scale, rotation, mu_t - scale * rotation @ mu_s


def _capture_from(data, folder, camera_model='PINHOLE', extra=()):
  """Writes a COLMAP model of a loaded Blender-layout split (OpenGL cameras) and links its images into folder."""
  (folder / 'sparse' / '0').mkdir(parents=True)
  (folder / 'images').mkdir()
  cameras, images = {}, {}
  focal = 1. / data.pixtocams[0][0, 0]
  for k, (i, c2w) in enumerate(zip(data.ids, data.camtoworlds.astype(np.float64))):
    name = f'view_{i:03d}.png'
    os.link(data.source_paths[k], folder / 'images' / name)
    rotation = (c2w[:, :3] @ np.diag([1., -1., -1.])).T  # World to OpenCV camera.
    cameras[k + 1] = cm.Camera(k + 1, camera_model, data.width, data.height,
                               np.array([focal, focal, data.width / 2., data.height / 2., *extra]))
    images[k + 1] = cm.Image(k + 1, algebra.rotation_to_quaternion(rotation), -rotation @ c2w[:, 3], k + 1, name,
                             np.zeros(0, cm.POINT2D))
  grid = np.stack(np.meshgrid(*[np.linspace(-.8, .8, 4)] * 3), -1).reshape(-1, 3)
  track = np.array([(k, 0) for k in images], cm.TRACK)
  points = {j: cm.Point3D(j, p, np.zeros(3, np.uint8), 0., track) for j, p in enumerate(grid)}
  cm.write_binary(cm.Model(cameras, images, points), str(folder / 'sparse' / '0'))


@pytest.fixture(name='generated_capture', scope='module')
def fixture_generated_capture(tmp_path_factory):
  """(the generated object scene's 'all views' train split, its COLMAP capture folder)."""
  root = tmp_path_factory.mktemp('capture')
  config = Config(dataset_loader='generated', data_dir=str(root / 'scene'), n_input_views=0,
                  generated_size=(24, 32), white_background=False)
  data = load_dataset('train', config)
  data.source_paths = [str(root / 'scene' / 'train' / f'r_{i}.png') for i in data.ids]
  _capture_from(data, root / 'capture')
  return data, root / 'capture'


def _capture_config(folder, **kwargs):
  return Config(**{'dataset_loader': 'capture', 'data_dir': str(folder), 'n_input_views': 0, 'llffhold': 4,
                   'white_background': False, **kwargs})


def test_exact_cameras_read_back_as_the_same_rays(generated_capture):
  data, folder = generated_capture
  config = _capture_config(folder, capture_rig='inward')
  capture = capture_loader.read_capture(config)
  both = load_dataset('train', config), load_dataset('test', config)
  rays = {i: (d.rays, k) for d in both for k, i in enumerate(d.ids)}
  scale, rotation, shift = _umeyama(data.camtoworlds[:, :, 3].astype(np.float64), capture.camtoworlds[:, :, 3])
  for k in range(len(data.ids)):
    got, position = rays[k]
    np.testing.assert_allclose(got.origins[position], scale * data.rays.origins[k] @ rotation.T + shift, atol=2e-6)
    np.testing.assert_allclose(got.viewdirs[position], data.rays.viewdirs[k] @ rotation.T, atol=2e-6)
  np.testing.assert_array_equal(np.concatenate([both[0].images, both[1].images])[np.argsort(both[0].ids + both[1].ids)],
                                data.images)
  up = data.camtoworlds[:, :, 1].mean(0)  # OpenGL: a camera's y axis is its up; their mean becomes +z.
  assert rotation @ (up / np.linalg.norm(up)) == pytest.approx([0., 0., 1.], abs=1e-6)


def test_distortion_is_inverted_at_every_pixel_of_a_downsampled_image(generated_capture, tmp_path):
  data, _ = generated_capture
  extra = (-.08, .02, 1e-3, -2e-3)
  _capture_from(data, tmp_path / 'distorted', 'OPENCV', extra)
  config = _capture_config(tmp_path / 'distorted', capture_rig='inward', factor=2)
  capture = capture_loader.read_capture(config)
  test = load_dataset('test', config)
  k = test.ids[0]
  cam_dirs = test.rays.directions[0].astype(np.float64) @ capture.camtoworlds[k, :, :3]  # World to camera.
  params = np.array([1. / data.pixtocams[0][0, 0]] * 2 + [data.width / 2., data.height / 2., *extra])
  u, v = distortion.distort(params, cam_dirs[..., 0] / cam_dirs[..., 2], cam_dirs[..., 1] / cam_dirs[..., 2])
  height, width = test.images.shape[1:3]
  np.testing.assert_allclose(params[0] * u + params[2], 2. * (np.arange(width) + .5) + 0. * u, atol=1e-3)
  np.testing.assert_allclose(params[1] * v + params[3], 2. * (np.arange(height)[:, None] + .5) + 0. * v, atol=1e-3)


def test_an_inward_capture_meshes_the_box_of_its_points_inside_the_cameras_orbit(generated_capture):
  """tools.mesh without --bounds: the loader registry's region, the sparse points carried into the loader's frame
  (by the similarity of the camera centres) that lie within the median camera distance of the centre."""
  _, folder = generated_capture
  config = _capture_config(folder, capture_rig='inward')
  capture = capture_loader.read_capture(config)
  model = cm.read_model(str(folder / 'sparse' / '0'))
  centres = np.stack([cm.camera_center(i) for i in sorted(model.images.values(), key=lambda i: i.name)])
  scale, rotation, shift = _umeyama(centres, capture.camtoworlds[:, :, 3])
  points = scale * np.stack([p.xyz for p in model.points.values()]) @ rotation.T + shift
  np.testing.assert_allclose(capture.points, points, atol=1e-9)
  inside = points[np.linalg.norm(points, axis=-1) < np.median(np.linalg.norm(capture.camtoworlds[:, :, 3], axis=-1))]
  assert 0 < len(inside)
  np.testing.assert_allclose(mesh_tool.scene_bounds(config, None), [inside.min(0), inside.max(0)], atol=1e-9)


def test_views_follow_the_documented_rule(generated_capture):
  _, folder = generated_capture
  config = _capture_config(folder, capture_rig='inward', n_input_views=3)
  capture = capture_loader.read_capture(config)
  order = capture_loader.arc_order(capture)
  azimuth = np.unwrap(np.arctan2(capture.camtoworlds[order, 1, 3], capture.camtoworlds[order, 0, 3]))
  assert (np.diff(azimuth) > 0).all()
  views = capture_loader.default_views(capture, 4, 3)
  assert views['test'] == order[::4]
  pool = [i for k, i in enumerate(order) if k % 4]
  assert views['train'] == [pool[0], pool[round((len(pool) - 1) / 2)], pool[-1]]
  assert load_dataset('train', config).ids == views['train']


def test_explicit_view_ids_for_captures_llff_and_blender(generated_capture, tmp_path):
  _, folder = generated_capture
  config = _capture_config(folder, capture_rig='inward', n_input_views=2, train_view_ids=(5, 2), test_view_ids=(7,))
  assert load_dataset('train', config).ids == [5, 2] and load_dataset('test', config).ids == [7]
  forward = Config(dataset_loader='generated', generated_rig='forward', data_dir=str(tmp_path / 'forward'),
                   generated_size=(24, 32), n_input_views=2, train_view_ids=[3, 5])
  assert load_dataset('train', forward).ids == [3, 5]
  with pytest.raises(DatasetError, match=r'views \[8\] of the LLFF scene .* both training views'):
    load_dataset('train', dataclasses.replace(forward, train_view_ids=[8, 5]))
  obj = Config(dataset_loader='generated', data_dir=str(tmp_path / 'object'), generated_size=(24, 32),
               n_input_views=1, train_view_ids=[4], test_view_ids=[4])  # Blender splits are separate files.
  assert load_dataset('train', obj).ids == [4] and load_dataset('test', obj).ids == [4]


@pytest.mark.parametrize('bindings, message', [
    (dict(train_view_ids=[]), r'Config.train_view_ids = \[\]: the train split would be empty'),
    (dict(train_view_ids=[0, 99], n_input_views=2), r'ids \[99\] are outside the 24 views'),
    (dict(test_view_ids=[1, 1]), 'an id repeats'),
    (dict(train_view_ids=[1, 2], n_input_views=3), 'names 2 views but Config.n_input_views = 3'),
    (dict(n_input_views=40), 'Config.n_input_views = 40 exceeds the 18 training views of the capture'),
])
def test_bad_view_selections_are_one_line(generated_capture, bindings, message):
  _, folder = generated_capture
  with pytest.raises(DatasetError, match=message):
    load_dataset('train', _capture_config(folder, capture_rig='inward', **bindings))


def test_bad_captures_name_the_file(generated_capture, tmp_path):
  data, _ = generated_capture
  _capture_from(data, tmp_path / 'fisheye', 'OPENCV_FISHEYE', (0., 0., 0., 0.))
  with pytest.raises(DatasetError, match=r"camera 1 of image 'view_000.png': camera model 'OPENCV_FISHEYE' is not "
                                         r"supported; expected one of \['SIMPLE_PINHOLE'"):
    load_dataset('train', _capture_config(tmp_path / 'fisheye'))
  _capture_from(data, tmp_path / 'missing')
  os.remove(tmp_path / 'missing' / 'images' / 'view_003.png')
  with pytest.raises(DatasetError, match=r"1 of the 24 images the COLMAP model .* registers are not in .*view_003"):
    load_dataset('train', _capture_config(tmp_path / 'missing'))
  with pytest.raises(DatasetError, match='no COLMAP sparse model in'):
    load_dataset('train', _capture_config(tmp_path / 'missing', capture_model='sparse/1'))


def _edited_capture(data, folder, edit):
  """A capture of data in folder whose COLMAP model edit(model) changed (in place) before it is written again."""
  _capture_from(data, folder)
  model = cm.read_model(str(folder / 'sparse' / '0'))
  edit(model)
  cm.write_binary(model, str(folder / 'sparse' / '0'))
  return folder


@pytest.mark.parametrize('index, value', [(0, -20.), (1, 0.), (2, np.nan), (3, np.inf)])
def test_a_camera_without_positive_focal_lengths_or_finite_values_is_named(generated_capture, tmp_path, index, value):
  data, _ = generated_capture
  folder = _edited_capture(data, tmp_path / 'capture', lambda model: model.cameras[3].params.__setitem__(index, value))
  cameras = str(folder / 'sparse' / '0' / 'cameras.bin')
  with pytest.raises(DatasetError, match=rf"^{re.escape(repr(cameras))}: camera 3 of image 'view_002.png': "
                                         r"PINHOLE 32 x 24 with parameters \[.*\]; expected positive focal lengths"):
    load_dataset('train', _capture_config(folder))


@pytest.mark.parametrize('value', [np.nan, -np.inf])
def test_a_3d_point_that_is_not_finite_is_named_with_points3d(generated_capture, tmp_path, value):
  data, _ = generated_capture
  folder = _edited_capture(data, tmp_path / 'capture', lambda model: model.points[5].xyz.__setitem__(1, value))
  points = str(folder / 'sparse' / '0' / 'points3D.bin')
  with pytest.raises(DatasetError, match=rf"^{re.escape(repr(points))}: 3D point 5 is at \[.*\]; expected finite"):
    load_dataset('train', _capture_config(folder))


def test_points_behind_a_camera_are_named_with_points3d(generated_capture, tmp_path):
  data, _ = generated_capture
  folder = _edited_capture(data, tmp_path / 'capture', lambda model: model.points.update(
      {j: dataclasses.replace(p, xyz=p.xyz * 1e3) for j, p in model.points.items()}))  # Beyond the cameras.
  with pytest.raises(DatasetError, match=r"points3D.bin': the 3D points image 'view_000.png' sees give it the "
                                         r"depth range \[-.*\]; expected 0 < near <= far"):
    load_dataset('train', _capture_config(folder))


def test_a_rotated_photo_is_named_against_its_own_cameras_size(generated_capture, tmp_path):
  data, _ = generated_capture
  _capture_from(data, tmp_path / 'capture')
  rotated = tmp_path / 'capture' / 'images' / 'view_000.png'  # The first image, the size others were judged by.
  image = np.asarray(Image.open(rotated))
  rotated.unlink()  # A link to the generated scene's file: replaced, not written through.
  Image.fromarray(np.rot90(image).copy()).save(rotated)
  with pytest.raises(DatasetError, match=rf"^{re.escape(repr(str(rotated)))} is 24 x 32 pixels; its COLMAP camera "
                                         r"is 32 x 24"):
    load_dataset('test', _capture_config(tmp_path / 'capture', capture_rig='inward', test_view_ids=(0, 1),
                                 n_input_views=2, train_view_ids=(2, 3)))


@needs_cup
def test_cup_cameras_reproject_the_points_with_colmaps_own_error():
  """The model's points, carried into the loader's frame, projected by the loader's cameras (pose, intrinsics,
  distortion) land on the pixels COLMAP observed them at, as far off as COLMAP says: the mean over every
  observation equals the model's (its points' errors weighted by their tracks, 0.63 px)."""
  capture = capture_loader.read_capture(_capture_config(CUP, llffhold=8))
  model = cm.read_model(str(CUP / 'sparse' / '0'))
  images = sorted(model.images.values(), key=lambda i: i.name)
  scale, rotation, shift = _umeyama(np.stack([cm.camera_center(i) for i in images]), capture.camtoworlds[:, :, 3])
  errors = []
  for k, image in enumerate(images):
    seen = image.points2d[image.points2d['point3d_id'] >= 0]
    points = scale * np.stack([model.points[int(i)].xyz for i in seen['point3d_id']]) @ rotation.T + shift
    local = (points - capture.camtoworlds[k, :, 3]) @ capture.camtoworlds[k, :, :3]
    params = capture.params[k]
    u, v = distortion.distort(params, local[:, 0] / local[:, 2], local[:, 1] / local[:, 2])
    errors.append(np.hypot(params[0] * u + params[2] - seen['x'], params[1] * v + params[3] - seen['y']))
  tracks = np.array([len(p.track) for p in model.points.values()])
  expected = (np.array([p.error for p in model.points.values()]) * tracks).sum() / tracks.sum()
  assert np.concatenate(errors).mean() == pytest.approx(expected, rel=1e-6)


@needs_cup
def test_cup_is_an_inward_capture_with_bounds_from_its_points():
  config = _capture_config(CUP, llffhold=8, n_input_views=3, factor=4)
  assert loader.ndc(config) is False and loader.filed_as(config) == ('capture', 'cup')
  train, test = load_dataset('train', config), load_dataset('test', config)
  assert train.images.shape == (3, 150, 200, 3) and len(test.ids) == 10 and not set(train.ids) & set(test.ids)
  capture = capture_loader.read_capture(config)
  assert 0 < train.near == capture.bounds[:, 0].min() < capture.bounds[:, 1].max() == train.far
  distances = np.linalg.norm(capture.camtoworlds[:, :, 3], axis=-1)
  assert np.median(distances) == pytest.approx(capture_loader.CAMERA_DISTANCE)


def test_forward_captures_follow_llffs_pipeline(tmp_path):
  """A forward capture (the generated forward scene's cameras as a COLMAP model) gives the rays of the LLFF loader
  on the poses_bounds.npy that LLFF's converter would write from that model (rows [down, right, back | centre |
  h, w, f], bounds from the points each image sees)."""
  scene = tmp_path / 'forward'
  load_dataset('train', Config(dataset_loader='generated', generated_rig='forward', data_dir=str(scene),
                               generated_size=(24, 32), n_input_views=0))
  rows = np.load(scene / 'poses_bounds.npy')
  (tmp_path / 'capture' / 'sparse' / '0').mkdir(parents=True)
  os.symlink(scene / 'images', tmp_path / 'capture' / 'images')
  height, width, focal = rows[0, :15].reshape(3, 5)[:, 4]
  cameras = {1: cm.Camera(1, 'SIMPLE_PINHOLE', int(width), int(height), np.array([focal, width / 2., height / 2.]))}
  images = {}
  for k, row in enumerate(rows):
    pose = row[:15].reshape(3, 5)
    rotation = np.stack([pose[:, 1], pose[:, 0], -pose[:, 2]], 1).T  # World to OpenCV camera.
    images[k + 1] = cm.Image(k + 1, algebra.rotation_to_quaternion(rotation), -rotation @ pose[:, 3], 1,
                             f'image{k:03d}.png', np.zeros(0, cm.POINT2D))
  rng = np.random.default_rng(0)
  lookat = rows[:, :15].reshape(-1, 3, 5)[:, :, 3].mean(0) - rows[:, :15].reshape(-1, 3, 5)[:, :, 2].mean(0) * 3.
  track = np.array([(k, 0) for k in images], cm.TRACK)
  points = {j: cm.Point3D(j, lookat + rng.normal(size=3), np.zeros(3, np.uint8), 0., track) for j in range(50)}
  model = cm.Model(cameras, images, points)
  cm.write_binary(model, str(tmp_path / 'capture' / 'sparse' / '0'))
  bounds = cm.depth_bounds(model)
  converted = np.concatenate([rows[:, :15], np.stack([bounds[k + 1] for k in range(len(rows))])], 1)
  (tmp_path / 'llff' / 'images').mkdir(parents=True)
  for name in os.listdir(scene / 'images'):
    os.link(scene / 'images' / name, tmp_path / 'llff' / 'images' / name)
  np.save(tmp_path / 'llff' / 'poses_bounds.npy', converted)
  capture = _capture_config(tmp_path / 'capture', llffhold=8, n_input_views=3)
  assert loader.ndc(capture) is True  # 'auto': every camera looks the same way.
  assert mesh_tool.scene_bounds(capture, None).tolist() == [[-1., -1., -1.], [1., 1., .99]]  # The NDC box.
  read = capture_loader.read_capture(capture)  # Its points carried along: their depths scale as LLFF scales the scene.
  xyz = np.stack([p.xyz for p in points.values()])
  for k, image in enumerate(images.values()):
    depths = (xyz @ algebra.quaternion_to_rotation(image.qvec).T + image.tvec)[:, 2]
    loaded = ((read.points - read.camtoworlds[k, :, 3]) @ read.camtoworlds[k, :, :3])[:, 2]
    np.testing.assert_allclose(loaded, depths / (.75 * converted[:, 15:].min()), rtol=1e-9)
  llff = Config(dataset_loader='llff', data_dir=str(tmp_path), llff_scan='llff', n_input_views=3)
  for split in ('train', 'test'):
    ours, theirs = load_dataset(split, capture), load_dataset(split, llff)
    assert ours.ids == theirs.ids and (ours.near, ours.far) == (0., 1.)
    for field in ('origins', 'directions', 'radii'):
      np.testing.assert_allclose(getattr(ours.rays, field), getattr(theirs.rays, field), atol=1e-5)
    np.testing.assert_array_equal(ours.images, theirs.images)
  # RegNeRF's random poses: LLFF's rule (all n draws, as LLFF with the released bugs fixed).
  capture, llff = (dataclasses.replace(c, n_random_poses=5, regnerf_fix_released_bugs=True) for c in (capture, llff))
  # Its poses are OpenCV cameras in the capture's space, LLFF's OpenGL ones in LLFF's: the same patches.
  pixels = random_poses.patch_pixels(np.arange(5), np.zeros(5, int), np.full(5, 3), 4)
  ours, theirs = (caster.cast(loader.random_pose_cameras(data, c, np.random.default_rng(0)), pixels,
                              random_poses.patch_space(data.space))
                  for c, data in ((c, load_dataset('train', c)) for c in (capture, llff)))
  for field, a, b in zip(ours._fields, ours, theirs):
    np.testing.assert_allclose(a, b, atol=1e-5, err_msg=field)


def test_inward_captures_draw_regnerfs_random_poses_by_dtus_rule(generated_capture):
  config = _capture_config(generated_capture[1], n_input_views=3, n_random_poses=200,
                           random_pose_focusptjitter=False)
  data = load_dataset('train', config)
  cameras = loader.random_pose_cameras(data, config, np.random.default_rng(0))
  poses = cameras.camtoworlds
  assert poses.shape == (200, 3, 4) and cameras.distortion is None and not data.space.ndc_focal
  np.testing.assert_allclose(cameras.pixtocams, np.broadcast_to(data.pixtocams.mean(0), (200, 3, 3)), rtol=1e-6)
  centres = capture_loader.read_capture(config).camtoworlds[:, :, 3]
  # In a box of half-sides radius x max |centre| per axis about the mean camera (rotated: bounded by its norm).
  reach = config.random_pose_radius * np.linalg.norm(np.abs(centres).max(0)) + np.linalg.norm(centres.mean(0))
  assert np.linalg.norm(poses[:, :, 3], axis=-1).max() <= reach + 1e-6
  # Without the focus jitter every +z axis passes through the centre (the origin of the capture's frame).
  camtoworlds = capture_loader.read_capture(config).camtoworlds
  np.testing.assert_allclose(algebra.focus_point(camtoworlds), 0., atol=1e-9)
  to_centre = -poses[:, :, 3]
  along = np.sum(to_centre * poses[:, :, 2], -1)
  np.testing.assert_allclose(to_centre, along[:, None] * poses[:, :, 2], atol=1e-9)
  assert np.all(along > 0)
  # Their patches are the capture's world rays from the poses' centres (not moved onto DTU's origin plane).
  regnerf = dataclasses.replace(config, depth_tvnorm_loss_mult=.1, batch_size=64, batch_size_random=128)
  patches = make_batcher(data, regnerf)(1).patch_rays
  drawn = loader.random_pose_cameras(data, regnerf, np.random.default_rng([regnerf.np_rng_seed,
                                                                          random_poses.POSES_STREAM]))
  centres = [np.linalg.norm(drawn.camtoworlds[:, :, 3] - o, axis=-1).min() for o in patches.origins.reshape(-1, 3)]
  assert max(centres) < 1e-5 and (patches.near == data.near).all() and (patches.far == data.far).all()


def test_the_loaders_earlier_name_is_read_as_capture_in_gin_files_run_folders_and_metrics(tmp_path):
  with pytest.warns(UserWarning, match="'colmap' is an earlier name of 'capture'"):
    config = config_loader.load_config([], ["Config.dataset_loader = 'colmap'", "Config.data_dir = '/x'"])
  assert config.dataset_loader == 'capture'
  stored = {**run_dir.fingerprint(config), 'Config.dataset_loader': 'colmap'}  # A run started before the rename.
  assert run_dir.differences(stored, config) == ''
  assert run_dir.differences({**stored, 'Config.dataset_loader': 'llff'}, config).startswith('Config.dataset_loader')
  record = results.make_record('capture', 'cup', 3, 'freenerf', 5, [{'id': 0, 'psnr': 20.}], True)
  (tmp_path / 'metrics.json').write_text(json.dumps({**record, 'dataset': 'colmap'}))
  assert results.read_record(tmp_path / 'metrics.json') == record
