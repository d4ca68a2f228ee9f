"""Depth priors as files (internal/datasets/depth_prior.py) for every loader, their resampling and their one-line
errors; the sparse structure-from-motion prior of captures (internal/datasets/sfm_depth.py), both forms, against a
brute-force projection of a model written from the generated scene's exact cameras and depths."""

import dataclasses
import os
import subprocess
import sys
import warnings

import jax.numpy as jnp
import numpy as np
import png
from PIL import Image
import pytest

from internal import config_loader
from internal.configs import Config
from internal.cameras import algebra
from internal.datasets import DatasetError, colmap_model as cm, depth_prior, load_dataset, sfm_depth
from internal.datasets import capture as capture_loader
from internal.losses import depth_pearson, depth_ranking
from tests.conftest import SHARED_DATA
from tests.test_datasets_capture import _capture_from
from tests.test_datasets_dtu_layouts import config as dtu_config, synthetic_projections, write_idr
from tools import synthetic_depth

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CUP = SHARED_DATA / 'colmap' / 'cup'
SHARED_SIZE = (32, 40)  # The session's shared generated scene (conftest.scene_dir) at test_checkpoints.TINY's size.


def _write_png16(path, values):
  with open(path, 'wb') as f:
    png.Writer(width=values.shape[1], height=values.shape[0], greyscale=True, bitdepth=16).write(
        f, values.astype(np.uint16).tolist())


# ---------------------------------------------------------------- resampling

def test_resampling_is_the_identity_at_the_same_size_and_a_block_mean_when_shrinking_by_an_integer():
  values = np.random.default_rng(0).uniform(1., 2., (12, 16))
  np.testing.assert_allclose(depth_prior.resample(values, 12, 16), values, rtol=1e-6)
  blocks = values.reshape(3, 4, 4, 4).mean((1, 3))
  np.testing.assert_allclose(depth_prior.resample(values, 3, 4), blocks, rtol=1e-6)


def test_growing_is_linear_between_pixel_centres_and_constant_beyond_them():
  values = np.array([[1., 3.]])
  out = depth_prior.resample(values, 1, 8)[0]
  centres = (np.arange(8) + .5) / 4. - .5  # Input coordinates of the output pixel centres.
  np.testing.assert_allclose(out, np.interp(centres, [0., 1.], [1., 3.]), rtol=1e-6)


def test_holes_do_not_bleed_and_pixels_mostly_without_prior_get_none():
  values = np.full((4, 4), 2.)
  values[:, :2] = 5.
  values[0, 0], values[1, 0], values[0, 1] = 0., np.nan, np.inf  # 3 of the top-left block's 4 pixels: no prior.
  values[2, 2] = 0.  # 1 of the bottom-right block's 4.
  out = depth_prior.resample(values, 2, 2)
  assert out[0, 0] == 0.  # A quarter of it has a prior: less than MIN_COVER.
  assert out[1, 1] == pytest.approx(2.)  # The mean of its 3 valid pixels, not pulled towards 0.
  assert out[0, 1] == pytest.approx(2.) and out[1, 0] == pytest.approx(5.)


# ---------------------------------------------------------------- every loader

def _write_maps(folder, data, scale=2, png_first=False):
  """One map per image of data at scale x its size (values: the row index + 1 + 100 * view), the first as a 16-bit
  PNG when png_first; returns the maps as written."""
  os.makedirs(folder, exist_ok=True)
  written = []
  for k, path in enumerate(data.image_paths):
    values = (np.arange(data.height * scale)[:, None] + 1. + 100. * k) * np.ones((1, data.width * scale))
    stem = os.path.join(folder, os.path.splitext(os.path.basename(path))[0])
    if png_first and k == 0:
      _write_png16(stem + '.png', values)
    else:
      np.save(stem + '.npy', values.astype(np.float32))
    written.append(values)
  return written


def _check_loader(config, tmp_path, png_first=False):
  """The maps of the training views load at the training size; the folder holds none of the test views."""
  config = dataclasses.replace(config, depth_prior_dir=str(tmp_path / 'priors'), depth_prior_kind='disparity',
                               depth_rank_loss_mult=1.)
  train = load_dataset('train', config)
  written = _write_maps(tmp_path / 'priors', train, png_first=png_first)
  maps = depth_prior.load_maps(train, config)
  assert maps.shape == (len(train.ids), train.height, train.width) and maps.dtype == np.float32
  for got, values in zip(maps, written):  # Rescaled by a power of two, its largest value in [1, 2).
    np.testing.assert_allclose(got, depth_prior.rescaled(values).reshape(train.height, 2, train.width, 2).mean((1, 3)),
                               rtol=1e-6)
    assert 2**-1 < got.max() < 2


def test_generated_object_and_forward_scenes(tmp_path, scene_dir):
  _check_loader(Config(data_dir=str(scene_dir), generated_size=SHARED_SIZE, n_input_views=3), tmp_path / 'object',
                png_first=True)
  _check_loader(Config(data_dir=str(tmp_path / 'forward_scene'), generated_rig='forward', generated_size=(24, 32),
                       n_input_views=2, near=0., far=1., white_background=False), tmp_path / 'forward')


def test_llff_and_blender(tmp_path, llff_root, blender_root):
  _check_loader(Config(dataset_loader='llff', data_dir=str(llff_root), llff_scan='toy', factor=8, n_input_views=2),
                tmp_path / 'llff')
  _check_loader(Config(dataset_loader='blender', data_dir=str(blender_root), blender_scene='toy',
                       blender_split='first_n', n_input_views=2), tmp_path / 'blender', png_first=True)


def test_dtu(tmp_path):
  write_idr(tmp_path / 'dtu', 'scan24', synthetic_projections())
  _check_loader(dtu_config(tmp_path / 'dtu', 'scan24', n_input_views=3), tmp_path)


def test_captures(tmp_path, scene_dir):
  data = load_dataset('train', Config(data_dir=str(scene_dir), generated_size=SHARED_SIZE, n_input_views=0))
  data.source_paths = data.image_paths
  _capture_from(data, tmp_path / 'capture')
  _check_loader(Config(dataset_loader='capture', data_dir=str(tmp_path / 'capture'), n_input_views=3, llffhold=4,
                       white_background=False), tmp_path)


# ---------------------------------------------------------------- bad maps: one line naming the file

@pytest.fixture(name='prior_setup')
def fixture_prior_setup(tmp_path, llff_root):
  config = Config(dataset_loader='llff', data_dir=str(llff_root), llff_scan='toy', factor=8, n_input_views=2,
                  depth_prior_dir=str(tmp_path / 'priors'), depth_prior_kind='depth', depth_pearson_loss_mult=.1)
  train = load_dataset('train', config)
  _write_maps(tmp_path / 'priors', train)
  first = tmp_path / 'priors' / (os.path.splitext(os.path.basename(train.image_paths[0]))[0] + '.npy')
  return config, train, first


def _bad(config, train, pattern):
  with pytest.raises(DatasetError, match=pattern) as err:
    depth_prior.load_maps(train, config)
  assert '\n' not in str(err.value)


@pytest.mark.parametrize('write, message', [
    (lambda p: os.remove(p), r"no depth map of training image .*img0\d\.png.*img0\d\.npy.*img0\d\.png"),
    (lambda p: p.write_bytes(b'not an array'), r'cannot read depth map .*img0\d\.npy'),
    (lambda p: np.save(p, np.ones((12, 16, 3))), r'img0\d\.npy.*shape \[12, 16, 3\]'),
    (lambda p: np.save(p, np.array([['a'] * 16] * 12)), r'img0\d\.npy.*<U1 array'),
    (lambda p: np.save(p, np.ones((12, 12))), r'img0\d\.npy.* 12 x 12 pixels, not the aspect ratio'),
    (lambda p: np.save(p, np.where(np.eye(12, 16) > 0, np.nan, 0.)), r'img0\d\.npy.*holds no value'),
])
def test_bad_maps_are_one_line_naming_the_file(prior_setup, write, message):
  config, train, first = prior_setup
  write(first)
  _bad(config, train, message)


def _prior_patches(maps):
  """Each map [N, H, W] as one patch [N, H * W]."""
  return jnp.asarray(maps.reshape(len(maps), -1))


@pytest.mark.parametrize('scale', [1e40, 1e300, 1e-40])
def test_a_map_in_units_float32_does_not_hold_trains_as_the_same_map(prior_setup, scale):
  config, train, first = prior_setup
  plain = depth_prior.load_maps(train, config)
  for path in first.parent.glob('*.npy'):
    np.save(path, np.load(path).astype(np.float64) * scale)
  with warnings.catch_warnings():
    warnings.simplefilter('error')  # Not even numpy's 'overflow encountered in cast'.
    scaled = depth_prior.load_maps(train, config)
  assert np.isfinite(scaled).all() and np.all(np.abs(scaled).max((1, 2)) < 2)
  np.testing.assert_allclose(scaled / scaled.max((1, 2), keepdims=True), plain / plain.max((1, 2), keepdims=True),
                             rtol=1e-6)
  rendered = jnp.asarray(np.random.default_rng(0).uniform(1., 2., (len(plain), plain[0].size)), jnp.float32)
  for loss in (depth_pearson.pearson_loss, lambda r, p: depth_ranking.ranking_loss(r, p, 1e-4, True)):
    assert float(loss(rendered, _prior_patches(scaled))) == pytest.approx(float(loss(rendered, _prior_patches(plain))),
                                                                          rel=1e-5)
    assert float(loss(rendered, _prior_patches(plain))) > .1


def test_a_map_scaled_by_a_power_of_two_loads_and_trains_bit_for_bit_alike(prior_setup):
  config, train, first = prior_setup
  plain = depth_prior.load_maps(train, config)
  for path in first.parent.glob('*.npy'):
    np.save(path, np.load(path) * 2.**-20)  # Exactly the same map, in other units: the same float32 map loads.
  np.testing.assert_array_equal(depth_prior.load_maps(train, config), plain)
  rendered = jnp.asarray(np.random.default_rng(0).uniform(1., 2., (len(plain), plain[0].size)), jnp.float32)
  for scale in (2.**-9, 2.**7):  # So the rescaling leaves the losses of maps in ordinary units exactly as they were.
    for loss in (depth_pearson.pearson_loss, lambda r, p: depth_ranking.ranking_loss(r, p, 1e-4, False)):
      assert float(loss(rendered, _prior_patches(plain * np.float32(scale)))) == float(loss(rendered,
                                                                                            _prior_patches(plain)))


def test_a_map_spanning_more_than_float32_holds_is_named(prior_setup):
  config, train, first = prior_setup
  values = np.load(first).astype(np.float64)
  values[:len(values) // 2] *= 1e-50  # Its top half would train as 0, "no prior", even rescaled.
  np.save(first, values)
  _bad(config, train, r"img0\d\.npy' holds values from 1e-50 to 12 \(in magnitude\), a wider span than float32 holds")


def test_a_png_that_is_not_16_bit_grey_is_named(prior_setup):
  config, train, first = prior_setup
  os.remove(first)
  Image.fromarray(np.full((12, 16), 7, np.uint8)).save(str(first)[:-4] + '.png')
  _bad(config, train, r"img0\d\.png' is a 8-bit PNG.*expected 16-bit grey")


def test_a_missing_folder_and_a_pack_without_names(prior_setup):
  config, train, _ = prior_setup
  _bad(dataclasses.replace(config, depth_prior_dir=config.depth_prior_dir + '_nowhere'), train,
       r'Config.depth_prior_dir = .*_nowhere.* is not a folder')
  _bad(config, dataclasses.replace(train, image_paths=None), 'keeps no image file names')


@pytest.mark.parametrize('bindings, message', [
    (['Config.depth_rank_loss_mult = 1.'], 'need depth maps: set Config.depth_prior_dir'),
    (["Config.depth_prior_dir = '/tmp'", 'Config.depth_pearson_loss_mult = 1.'],
     "Config.depth_prior_kind = ''; expected one of \\['depth', 'disparity'\\]"),
    (["Config.depth_prior_dir = '/tmp'", "Config.depth_prior_kind = 'depth'", 'Config.depth_rank_loss_mult = 1.',
      'Config.depth_patch_size = 1'], 'Config.depth_patch_size = 1 and Config.depth_prior_rays = 512'),
    (['Config.sfm_depth_loss_mult = 1.'], "needs a capture.*Config.dataset_loader = 'generated'"),
])
def test_settings_that_cannot_work_are_refused_naming_them(bindings, message):
  with pytest.raises(ValueError, match=message):
    config_loader.load_config([], bindings)


@pytest.mark.parametrize('bindings, message', [
    (["Config.depth_prior_dir = '/tmp'", "Config.depth_prior_kind = 'depth'"], 'depth_prior_dir .* is not read'),
    (["Config.sfm_depth_model = '/tmp'"], 'sfm_depth_model .* is not read')])
def test_settings_that_would_not_be_read_warn(bindings, message):
  with pytest.warns(UserWarning, match=message):
    config_loader.load_config([], bindings)


def test_train_py_with_a_missing_map_is_one_line_and_status_2(tmp_path):
  out = subprocess.run(
      [sys.executable, 'train.py', '--gin_configs', 'configs/demo.gin', '--gin_bindings',
       f"Config.data_dir = '{tmp_path / 'scene'}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'",
       f"Config.depth_prior_dir = '{tmp_path}'", "Config.depth_prior_kind = 'disparity'",
       'Config.depth_rank_loss_mult = 1.'], cwd=ROOT, capture_output=True, text=True, timeout=600)
  assert out.returncode == 2, out.stderr
  lines = [line for line in out.stderr.splitlines() if line.strip()]
  assert len(lines) == 1 and 'no depth map of training image' in lines[0] and 'r_' in lines[0], out.stderr


# ---------------------------------------------------------------- synthetic maps for tests and studies

def test_synthetic_maps_are_an_affine_map_of_the_disparity_without_distortion_and_keep_holes():
  depth = np.linspace(2., 6., 12) * np.ones((10, 1))
  depth[4:7, 4:7] = 1.5  # An object in front.
  depth[0, :4] = 0.
  out = synthetic_depth.monocular_like(depth, np.random.default_rng(0), 1., 0., 0.)
  valid = depth > 0
  assert np.all(out[~valid] == 0.) and np.all(out[valid] > 0.)
  assert np.corrcoef(out[valid], 1. / depth[valid])[0, 1] == pytest.approx(1., abs=1e-6)
  bent = synthetic_depth.monocular_like(depth, np.random.default_rng(0), .5, 1., .02)
  assert .8 < np.corrcoef(bent[valid], 1. / depth[valid])[0, 1] < .999


# ---------------------------------------------------------------- structure-from-motion points

def _project(rotation, translation, camera, xyz):
  """Pixel (x, y) [P, 2] (COLMAP's: pixel centres at +0.5) and z [P] of points in one pinhole camera."""
  local = xyz @ rotation.T + translation
  f, cx, cy = camera.params[0], camera.params[2], camera.params[3]
  return np.stack([f * local[:, 0] / local[:, 2] + cx, f * local[:, 1] / local[:, 2] + cy], -1), local[:, 2]


def _capture_with_points(tmp_path, scene_dir, n_points=150, **settings):
  """A capture of the generated scene (object rig unless settings say otherwise; its whole training pool) whose
  points lie on its exact surfaces, each observed in every view that sees it (its depth there within 1% of the
  exact one), with random errors."""
  config = Config(data_dir=str(scene_dir), n_input_views=0, **settings)
  data = load_dataset('train', config, ground_truth=True)
  data.source_paths = data.image_paths
  _capture_from(data, tmp_path / 'capture')
  folder = str(tmp_path / 'capture' / 'sparse' / '0')
  model = cm.read_model(folder)
  rng = np.random.default_rng(0)
  points, observed = [], {image_id: [] for image_id in model.images}
  for k, image in enumerate(model.images.values()):  # Pixel centres of some views, back-projected.
    if k % 6:
      continue
    rows, cols = np.nonzero(data.depths[k] > 0)
    pick = rng.choice(len(rows), n_points // 4, replace=False)
    rotation = algebra.quaternion_to_rotation(image.qvec)
    camera = model.cameras[image.camera_id]
    z = data.depths[k][rows[pick], cols[pick]].astype(np.float64)
    local = np.stack([(cols[pick] + .5 - camera.params[2]) / camera.params[0] * z,
                      (rows[pick] + .5 - camera.params[3]) / camera.params[1] * z, z], -1)
    points.append((local - image.tvec) @ rotation)
  xyz = np.concatenate(points)
  tracks = [[] for _ in xyz]
  for k, image in enumerate(model.images.values()):
    camera = model.cameras[image.camera_id]
    pixel, z = _project(algebra.quaternion_to_rotation(image.qvec), image.tvec, camera, xyz)
    col, row = np.floor(pixel[:, 0]).astype(int), np.floor(pixel[:, 1]).astype(int)
    inside = (row >= 0) & (row < data.height) & (col >= 0) & (col < data.width) & (z > 0)
    exact = np.where(inside, data.depths[k][np.clip(row, 0, data.height - 1), np.clip(col, 0, data.width - 1)], 0.)
    for j in np.nonzero(inside & (np.abs(exact - z) < .01 * z))[0]:
      tracks[j].append((image.image_id, len(observed[image.image_id])))
      observed[image.image_id].append((pixel[j, 0], pixel[j, 1], j))
  for image_id, image in model.images.items():
    image.points2d = np.array(observed[image_id], cm.POINT2D)
  model.points = {j: cm.Point3D(j, p, np.zeros(3, np.uint8), float(rng.uniform(.2, 2.)), np.array(t, cm.TRACK))
                  for j, (p, t) in enumerate(zip(xyz, tracks)) if t}
  cm.write_text(model, folder)
  for name in cm.FILES:
    os.remove(os.path.join(folder, name + '.bin'))
  return model, data, tmp_path / 'capture'


def _brute_prior(model, names, height, width, scale, keep):
  """The prior by hand: per view and pixel the best-weighted serving point's z-depth x scale."""
  by_name = {i.name: i for i in model.images.values()}
  names_of = {i.image_id: i.name for i in model.images.values()}
  used = [p for p in model.points.values() if keep({names_of[i] for i in p.track['image_id']})]
  mean_error = np.mean([p.error for p in used for i in p.track['image_id'] if names_of[i] in names])
  depth, weight = np.zeros((2, len(names), height, width))
  for view, name in enumerate(names):
    image = by_name[name]
    camera = model.cameras[image.camera_id]
    for point in used:
      for x, y, point_id in image.points2d:
        if point_id != point.point_id:
          continue
        z = (algebra.quaternion_to_rotation(image.qvec) @ point.xyz + image.tvec)[2]
        row, col = int(y * height // camera.height), int(x * width // camera.width)
        w = np.exp(-(point.error / mean_error)**2)
        if w > weight[view, row, col]:
          depth[view, row, col], weight[view, row, col] = scale * z, w
  return depth, weight


@pytest.fixture(name='sfm_capture', scope='module')
def fixture_sfm_capture(tmp_path_factory):
  root = tmp_path_factory.mktemp('sfm')
  return _capture_with_points(root, root / 'scene')


def _sfm_config(folder, **kwargs):
  return Config(**{'dataset_loader': 'capture', 'data_dir': str(folder), 'n_input_views': 4, 'llffhold': 4,
                   'white_background': False, 'sfm_depth_loss_mult': 1., **kwargs})


def test_the_sfm_prior_is_the_points_of_two_or_more_training_views_at_their_observations(sfm_capture):
  model, data, folder = sfm_capture
  config = _sfm_config(folder)
  train = load_dataset('train', config)
  capture = capture_loader.read_capture(config)
  scale = np.linalg.norm(np.diff(capture.camtoworlds[:2, :, 3], axis=0)) / np.linalg.norm(
      np.diff(data.camtoworlds[:2, :, 3].astype(np.float64), axis=0))
  names = [capture.names[i] for i in train.ids]
  depth, weight = sfm_depth.training_prior(train, config)
  expected = _brute_prior(model, names, train.height, train.width, scale,
                          lambda track: len(track & set(names)) >= 2)
  np.testing.assert_array_equal(weight > 0, expected[1] > 0)
  np.testing.assert_allclose(depth, expected[0], rtol=1e-5)
  np.testing.assert_allclose(weight, expected[1], rtol=1e-5)
  assert (weight > 0).sum() > 20
  seen_once = _brute_prior(model, names, train.height, train.width, scale, lambda track: bool(track & set(names)))
  assert (seen_once[1] > 0).sum() > (weight > 0).sum()  # Points of one training view are left out.
  # Where a point was back-projected from a pixel centre, its depth is that pixel's exact depth.
  exact = load_dataset('train', dataclasses.replace(Config(data_dir=str(folder.parent / 'scene'), n_input_views=0)),
                       ground_truth=True).depths[[int(n[5:8]) for n in names]] * scale
  centre = np.isclose(depth, exact, rtol=1e-4) & (weight > 0)
  assert centre.sum() >= 5


def test_the_strict_form_reads_a_model_of_the_training_photos_in_its_own_frame(sfm_capture, tmp_path):
  model, _, folder = sfm_capture
  config = _sfm_config(folder)
  train = load_dataset('train', config)
  names = {capture_loader.read_capture(config).names[i] for i in train.ids}
  # Structure-from-motion on the training photos: another frame (a similarity), only their images and points.
  rotation = algebra.quaternion_to_rotation([.9, .1, -.3, .2])
  scale, shift = 3.7, np.array([1., -2., .5])
  images = {}
  for image_id, image in model.images.items():
    if image.name in names:
      r = algebra.quaternion_to_rotation(image.qvec) @ rotation.T
      images[image_id] = dataclasses.replace(image, qvec=algebra.rotation_to_quaternion(r),
                                             tvec=scale * image.tvec - r @ shift)
  points = {j: dataclasses.replace(p, xyz=scale * rotation @ p.xyz + shift) for j, p in model.points.items()}
  cm.write_binary(cm.Model(model.cameras, images, points), str(tmp_path / 'strict'))
  strict = dataclasses.replace(config, sfm_depth_model=str(tmp_path / 'strict'))
  for got, expected in zip(sfm_depth.training_prior(train, strict), sfm_depth.training_prior(train, config)):
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
  # A model that lacks a training image, or whose cameras are not the capture's, is named.
  # A training image the model left out gets no depth (said in a warning); the others keep theirs.
  missing = dict(images)
  left_out = missing.pop(next(iter(missing))).name
  cm.write_binary(cm.Model(model.cameras, missing, points), str(tmp_path / 'missing'))
  view = [capture_loader.read_capture(config).names[i] for i in train.ids].index(left_out)
  lacking = dataclasses.replace(config, sfm_depth_model=str(tmp_path / 'missing'))
  with pytest.warns(UserWarning, match=rf"missing.* did not register training images \['{left_out}'\]"):
    _, weight = sfm_depth.training_prior(train, lacking)
  assert not weight[view].any()
  others = [k for k in range(len(train.ids)) if k != view]
  kept = sfm_depth.training_prior(train, strict)
  assert (weight[others] > 0).sum() > 0 and np.all((weight[others] > 0) <= (kept[1][others] > 0))
  moved = {k: dataclasses.replace(i, tvec=i.tvec + np.random.default_rng(k).normal(size=3)) for k, i in images.items()}
  cm.write_binary(cm.Model(model.cameras, moved, points), str(tmp_path / 'moved'))
  with pytest.raises(DatasetError, match=r'moved.*cameras fit the capture\'s only to'):
    sfm_depth.training_prior(train, dataclasses.replace(config, sfm_depth_model=str(tmp_path / 'moved')))
  with pytest.raises(DatasetError, match='nowhere.* is not a folder'):
    sfm_depth.training_prior(train, dataclasses.replace(config, sfm_depth_model=str(tmp_path / 'nowhere')))


def test_the_similarity_carries_the_models_cameras_onto_the_captures(sfm_capture):
  model, _, folder = sfm_capture
  capture = capture_loader.read_capture(_sfm_config(folder))
  found = sfm_depth.align(model, capture, 'model')  # The loader's frame: centred, scaled, z up.
  by_name = {image.name: image for image in model.images.values()}
  cameras = np.stack([cm.camtoworld(by_name[name]) for name in capture.names])
  assert found.scale != pytest.approx(1.)
  np.testing.assert_allclose(found.cameras(cameras), capture.camtoworlds, atol=1e-9)


def test_evaluation_depths_hold_every_point_a_test_view_observed(sfm_capture):
  model, _, folder = sfm_capture
  config = _sfm_config(folder)
  test = load_dataset('test', config)
  capture = capture_loader.read_capture(config)
  names = [capture.names[i] for i in test.ids]
  depth = sfm_depth.evaluation_depths(test, config)
  found = sfm_depth.align(model, capture, 'model')
  expected = _brute_prior(model, names, test.height, test.width, found.scale, lambda track: True)[0]
  np.testing.assert_allclose(depth, expected, rtol=1e-5)


@pytest.mark.skipif(not (CUP / 'sparse' / '0').is_dir(), reason=f'the shared capture {CUP} is absent')
def test_the_cup_from_three_views_has_a_sparse_prior_in_front_of_its_cameras():
  config = _sfm_config(CUP, n_input_views=3, llffhold=8, factor=4)
  train = load_dataset('train', config)
  depth, weight = sfm_depth.training_prior(train, config)
  assert (weight > 0).sum() > 100 and np.all(weight <= 1.)
  assert train.near <= depth[weight > 0].min() and depth[weight > 0].max() <= train.far


def test_a_forward_captures_prior_is_the_ndc_t_where_each_pixels_ray_reaches_its_points_depth(tmp_path):
  forward = dict(generated_rig='forward', generated_size=(24, 32), near=0., far=1., white_background=False)
  model, _, folder = _capture_with_points(tmp_path, tmp_path / 'scene', 60, **forward)
  config = _sfm_config(folder, n_input_views=4, llffhold=8)
  train = load_dataset('train', config)
  capture = capture_loader.read_capture(config)
  assert capture.forward and (train.near, train.far) == (0., 1.)
  depth, weight = sfm_depth.training_prior(train, config)
  found = sfm_depth.align(model, capture, 'model')
  names = [capture.names[i] for i in train.ids]
  by_name = {image.name: image for image in model.images.values()}
  def depth_of(view, row, col, point_id):  # The NDC t at which the pixel's ray reaches the point's world z.
    world_z = (found.scale * found.rotation @ model.points[int(point_id)].xyz + found.shift)[2]
    origin, direction = train.rays.origins[view, row, col], train.rays.directions[view, row, col]
    return (1. + 2. / world_z - origin[2]) / direction[2]

  checked = 0
  for view, name in enumerate(names):
    image = by_name[name]
    for x, y, point_id in image.points2d:
      row, col = int(y * train.height // model.cameras[image.camera_id].height), int(
          x * train.width // model.cameras[image.camera_id].width)
      if weight[view, row, col] == 0 or not np.isclose(depth[view, row, col], depth_of(view, row, col, point_id),
                                                       rtol=1e-5):
        continue  # A pixel observing several points keeps the best-weighted one.
      checked += 1
  assert checked >= 0.5 * (weight > 0).sum() > 5
