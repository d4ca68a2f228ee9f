"""Loaders on the real scenes of shared/data: fern (LLFF), DTU scan24 (IDR layout), lego (Blender)."""

import json
import pathlib

import numpy as np
import pytest
from PIL import Image

from internal.configs import Config
from internal.cameras import algebra
from internal.datasets import DatasetError, dtu, llff, load_dataset, render_path_rays

DATA = pathlib.Path(__file__).resolve().parents[2] / 'shared' / 'data'
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f'real scenes absent: {DATA} does not exist')

DTU_PRESENT_TEST_IDS = [1, 9, 11, 14, 23, 26, 29, 31, 33, 35, 41, 43, 46]


def llff_config(**kw):
  return Config(dataset_loader='llff', data_dir=str(DATA / 'llff'), llff_scan='fern', factor=8, near=0., far=1.,
                **kw)


def dtu_config(**kw):
  kw.setdefault('allow_missing_test_views', True)
  return Config(dataset_loader='dtu', data_dir=str(DATA / 'dtu'), dtu_scan='dtu_scan24', factor=4, near=.5,
                far=3.5, white_background=False, **kw)


def blender_config(**kw):
  kw.setdefault('n_input_views', 8)
  return Config(dataset_loader='blender', data_dir=str(DATA / 'blender'), blender_scene='lego', factor=2,
                downsample_mode='area', **kw)


def bilinear(field, rows, cols):
  """field [N,H,W,C] sampled at continuous pixel-index positions (rows [N], cols [N]) per image."""
  r0, c0 = np.floor(rows).astype(int), np.floor(cols).astype(int)
  fr, fc = (rows - r0)[:, None], (cols - c0)[:, None]
  idx = np.arange(len(rows))
  f = field.astype(np.float64)
  return ((1 - fr) * (1 - fc) * f[idx, r0, c0] + (1 - fr) * fc * f[idx, r0, c0 + 1] +
          fr * (1 - fc) * f[idx, r0 + 1, c0] + fr * fc * f[idx, r0 + 1, c0 + 1])


def nearest_point(origins, dirs):
  """Least-squares point nearest to lines (origins [N,3], dirs [N,3]) and each line's distance to it."""
  u = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
  proj = np.eye(3) - u[:, :, None] * u[:, None, :]
  point = np.linalg.solve(proj.sum(0), (proj @ origins[:, :, None]).sum(0))[:, 0]
  return point, np.linalg.norm((proj @ (point - origins)[:, :, None])[:, :, 0], axis=-1)


def read_png(path):
  return np.asarray(Image.open(path), np.float32) / 255.


# ---------------------------------------------------------------- LLFF fern

@pytest.fixture(scope='module')
def fern():
  return {n: load_dataset('train', llff_config(n_input_views=n)) for n in (3, 6, 9)}, \
      load_dataset('test', llff_config())


def test_fern_ids_shapes_and_ndc(fern):
  train, test = fern
  assert train[3].ids == [1, 10, 19] and train[6].ids == [1, 4, 7, 12, 15, 19]
  assert train[9].ids == [1, 3, 5, 7, 10, 12, 14, 17, 19] and test.ids == [0, 8, 16]
  assert test.images.shape == (3, 378, 504, 3) and test.images.dtype == np.float32
  assert test.height == 378 and test.width == 504 and test.masks is None
  np.testing.assert_allclose(test.rays.origins[..., 2], -1., atol=1e-5)
  assert (np.linalg.norm(test.rays.viewdirs, axis=-1) > 1. - 1e-6).all()
  assert (test.rays.near == 0.).all() and (test.rays.far == 1.).all()
  np.testing.assert_array_equal(test.images[1], read_png(DATA / 'llff/fern/images_8/image008.png'))


def test_fern_last_column_radii_released(fern):
  """The last column repeats the second-to-last column distance, not the last (about 4e-4 apart, which
  moves the radii, a mean of row and column distances, by about 2e-4)."""
  _, test = fern
  o = test.rays.origins[0].astype(np.float64)
  dx = np.linalg.norm(np.diff(o, axis=0), axis=-1)
  dx = np.concatenate([dx, dx[-2:-1]], 0)
  dy = np.linalg.norm(np.diff(o, axis=1), axis=-1)
  released = .5 * (dx[:, -1] + dy[:, -2]) * 2. / np.sqrt(12.)
  former = .5 * (dx[:, -1] + dy[:, -1]) * 2. / np.sqrt(12.)
  np.testing.assert_allclose(test.rays.radii[0, :, -1, 0], released, rtol=2e-5)
  assert np.max(np.abs(former / released - 1.)) > 1.5e-4


def test_fern_rays_through_one_point(fern):
  """Project a point into every camera of poses_bounds.npy; the loaders' rays there meet in one point."""
  train, test = fern
  data = train[9]
  pb = np.load(DATA / 'llff/fern/poses_bounds.npy')
  poses, f = pb[:, :15].reshape(-1, 3, 5), pb[0, 14] / 8.
  point = poses[0, :, 3] - 30. * poses[0, :, 2] + 2. * poses[0, :, 1]
  rows, cols = [], []
  for i in data.ids:
    rel = point - poses[i, :, 3]
    right, up, back = poses[i, :, 1] @ rel, -poses[i, :, 0] @ rel, poses[i, :, 2] @ rel
    cols.append(504 / 2 + f * right / -back - .5)
    rows.append(378 / 2 - f * up / -back - .5)
  dirs = bilinear(data.rays.viewdirs, np.array(rows), np.array(cols))
  centres = data.camtoworlds[:, :, 3].astype(np.float64)
  hit, dist = nearest_point(centres, dirs)
  assert dist.max() < 1e-5 * np.linalg.norm(hit - centres, axis=-1).min()
  # Translations scaled by 1/(0.75 min bound); recentering is rigid, so camera distances scale by exactly that.
  scale = 1. / (.75 * pb[:, 15:].min())
  file_gaps = np.linalg.norm(poses[data.ids, :, 3] - poses[data.ids[0], :, 3], axis=-1)
  np.testing.assert_allclose(np.linalg.norm(centres - centres[0], axis=-1), scale * file_gaps, rtol=1e-5,
                             atol=1e-6)


def test_fern_cameras_recentered_over_all_images(fern):
  train, test = fern
  c2w, bounds, focal = llff.process_poses(np.load(DATA / 'llff/fern/poses_bounds.npy'))
  np.testing.assert_allclose(algebra.poses_avg(c2w), np.eye(3, 4), atol=1e-9)
  assert np.isclose(bounds.min(), 1. / .75) and np.isclose(focal, 3260.526, atol=1e-3)
  np.testing.assert_allclose(train[9].camtoworlds, c2w[train[9].ids], atol=1e-6)
  np.testing.assert_allclose(test.camtoworlds, c2w[test.ids], atol=1e-6)
  np.testing.assert_allclose(np.linalg.inv(test.pixtocams[0])[0, 0], 3260.526 / 8, atol=1e-3)


def test_fern_ndc_rays_map_back_onto_world_rays(fern):
  """NDC points o' + t d' back-projected (z = 2/(z'-1)) lie on the world ray (camera centre, viewdir)."""
  _, test = fern
  f = np.load(DATA / 'llff/fern/poses_bounds.npy')[0, 14] / 8.
  rng = np.random.default_rng(0)
  n, r, c = rng.integers(3, size=50), rng.integers(378, size=50), rng.integers(504, size=50)
  o, d = test.rays.origins[n, r, c].astype(np.float64), test.rays.directions[n, r, c].astype(np.float64)
  for t in (0., .4, .9):
    p = o + t * d
    z = 2. / (p[:, 2] - 1.)
    world = np.stack([-p[:, 0] * z * 504 / (2 * f), -p[:, 1] * z * 378 / (2 * f), z], -1)
    rel = world - test.camtoworlds[n, :, 3]
    v = test.rays.viewdirs[n, r, c].astype(np.float64)
    off_line = np.linalg.norm(np.cross(rel, v), axis=-1) / np.linalg.norm(v, axis=-1)
    assert off_line.max() < 1e-4 * np.linalg.norm(rel, axis=-1).max()


def test_fern_render_path_on_demand():
  rays = render_path_rays(llff_config(render_path_frames=4))
  assert rays.origins.shape == (4, 378, 504, 3)
  np.testing.assert_allclose(rays.origins[..., 2], -1., atol=1e-5)


# ---------------------------------------------------------------- DTU scan24 (IDR layout)

@pytest.fixture(scope='module')
def dtu24():
  return {n: load_dataset('train', dtu_config(n_input_views=n)) for n in (3, 9)}, load_dataset('test', dtu_config())


def test_dtu_ids_and_shapes(dtu24):
  train, test = dtu24
  assert train[3].ids == [25, 22, 28] and train[9].ids == [25, 22, 28, 40, 44, 48, 0, 8, 13]
  assert test.ids == DTU_PRESENT_TEST_IDS
  assert train[9].images.shape == (9, 300, 400, 3) and test.images.shape == (13, 300, 400, 3)
  assert test.masks.shape == (13, 300, 400, 3) and test.masks.dtype == np.float32 and train[9].masks is None
  assert test.near == .5 and test.far == 3.5
  np.testing.assert_allclose(test.rays.origins[..., 2], 0., atol=1e-5)   # Moved onto the plane z = 0.


def test_dtu_six_views_are_a_prefix():
  assert load_dataset('train', dtu_config(n_input_views=6)).ids == [25, 22, 28, 40, 44, 48]


def test_dtu_images_and_masks_released_downsampling(dtu24):
  _, test = dtu24
  k = test.ids.index(9)
  img = read_png(DATA / 'dtu/dtu_scan24/images/000009.png')
  expected = (img[1::4, 1::4] + img[2::4, 1::4] + img[1::4, 2::4] + img[2::4, 2::4]) / 4.
  np.testing.assert_allclose(test.images[k], expected, atol=1e-6)
  binary = (np.asarray(Image.open(DATA / 'dtu/dtu_scan24/mask/009.png'))[..., :3] == 255).astype(np.float32)
  expected = (binary[1::4, 1::4] + binary[2::4, 1::4] + binary[1::4, 2::4] + binary[2::4, 2::4]) / 4.
  np.testing.assert_array_equal(test.masks[k], expected)
  assert set(np.unique(test.masks)) <= {0., .25, .5, .75, 1.}
  assert 0. < (test.masks == 1).mean() < 1.


def test_dtu_intrinsics_scaled_by_factor(dtu24):
  train, _ = dtu24
  k = np.linalg.inv(train[9].pixtocams[train[9].ids.index(0)].astype(np.float64))
  np.testing.assert_allclose(k[[0, 1, 0, 1], [0, 1, 2, 2]], np.array([2892.33, 2883.18, 823.21, 619.07]) / 4,
                             atol=.01)
  assert np.abs(train[9].camtoworlds[:, :, 3]).max() <= 1. + 1e-6   # Rescaled over all 49 cameras.


def test_dtu_cameras_recentered_and_rescaled_over_all_49(dtu24):
  train, test = dtu24
  _, _, projections = dtu.scan_setup(dtu_config())
  pixtocams, poses = dtu.normalized_cameras(projections, 4)
  assert len(poses) == 49
  np.testing.assert_allclose(algebra.poses_avg(poses), np.eye(3, 4), atol=1e-9)
  assert np.isclose(np.abs(poses[:, :, 3]).max(), 1.)
  np.testing.assert_allclose(test.camtoworlds, poses[test.ids], atol=1e-6)
  np.testing.assert_allclose(train[9].pixtocams, pixtocams[train[9].ids], rtol=1e-6)


def test_dtu_rays_through_one_point(dtu24):
  """Project the object centre with every view's P (world_mat); the loaders' rays there meet in one point."""
  train, test = dtu24
  cams = np.load(DATA / 'dtu/dtu_scan24/cameras_sphere.npz')
  point = np.append(cams['scale_mat_0'][:3, 3], 1.)
  for data in (train[9], test):
    uvw = np.stack([cams[f'world_mat_{i}'][:3] @ point for i in data.ids])
    cols, rows = uvw[:, 0] / uvw[:, 2] / 4. - .5, uvw[:, 1] / uvw[:, 2] / 4. - .5
    assert (cols > 0).all() and (rows > 0).all() and (cols < 399).all() and (rows < 299).all()
    dirs = bilinear(data.rays.directions, rows, cols)
    centres = data.camtoworlds[:, :, 3].astype(np.float64)
    hit, dist = nearest_point(centres, dirs)
    assert dist.max() < 1e-5 * np.linalg.norm(hit - centres, axis=-1).min()
    # Every origin lies on its camera's ray line.
    rel = data.rays.origins[:, ::37, ::41] - data.camtoworlds[:, None, None, :, 3]
    off = np.linalg.norm(np.cross(rel, data.rays.directions[:, ::37, ::41]), axis=-1)
    assert off.max() < 1e-4


def test_dtu_missing_test_views_error_names_files_and_setting():
  with pytest.raises(DatasetError) as err:
    load_dataset('test', dtu_config(allow_missing_test_views=False))
  message = str(err.value)
  assert 'allow_missing_test_views' in message and '000002.png' in message and '12 of 25' in message


def test_dtu_render_path_on_demand():
  rays = render_path_rays(dtu_config(render_path_frames=3, render_factor=8))
  assert rays.directions.shape == (3, 150, 200, 3)
  np.testing.assert_allclose(rays.origins[..., 2], 0., atol=1e-5)


# ---------------------------------------------------------------- Blender lego

@pytest.fixture(scope='module')
def lego():
  return load_dataset('train', blender_config()), load_dataset('test', blender_config())


def test_lego_views_resolution_and_white_background(lego):
  train, test = lego
  assert train.ids == [26, 86, 2, 55, 75, 93, 16, 73] and test.ids == list(range(0, 200, 8))
  assert train.images.shape == (8, 400, 400, 3) and test.images.shape == (25, 400, 400, 3)
  assert train.near == 2. and train.far == 6.
  np.testing.assert_array_equal(train.images[:, 0, 0], 1.)
  rgba = read_png(DATA / 'blender/lego/train/r_26.png').reshape(400, 2, 400, 2, 4).mean((1, 3))
  np.testing.assert_allclose(train.images[0], rgba[..., :3] * rgba[..., 3:] + 1. - rgba[..., 3:], atol=1e-6)


def test_lego_rays_pass_through_projected_point(lego):
  """Pinhole-project a world point with each transforms_*.json camera; that pixel's ray contains it."""
  for data, split in zip(lego, ('train', 'test')):
    meta = json.loads((DATA / f'blender/lego/transforms_{split}.json').read_text())
    f = 200. / np.tan(.5 * meta['camera_angle_x'])
    point = np.array([.3, -.2, .5])
    rows, cols = [], []
    for i in data.ids:
      c2w = np.array(meta['frames'][i]['transform_matrix'])
      x, y, z = c2w[:3, :3].T @ (point - c2w[:3, 3])
      cols.append(200. + f * x / -z - .5)
      rows.append(200. - f * y / -z - .5)
    dirs = bilinear(data.rays.directions, np.array(rows), np.array(cols))
    rel = point - data.rays.origins[:, 0, 0]
    off = np.linalg.norm(np.cross(rel, dirs), axis=-1) / np.linalg.norm(dirs, axis=-1)
    assert off.max() < 1e-5


def test_blender_nerf_config_rays_run_through_integer_pixel_coordinates():
  """The released Blender code's direction of pixel (column i, row j): R ((i - W/2)/f, -(j - H/2)/f, -1)."""
  from internal import config_loader  # Only this test reads a config file.
  path = pathlib.Path(__file__).resolve().parents[1] / 'configs' / 'nerf' / 'blender8_nerf.gin'
  config = config_loader.load_config([str(path)], [f"Config.data_dir = '{DATA / 'blender'}'", 'Config.factor = 8'])
  for split in ('train', 'test'):
    data = load_dataset(split, config)
    meta = json.loads((DATA / f'blender/lego/transforms_{split}.json').read_text())
    f = 50. / np.tan(.5 * meta['camera_angle_x'])  # 100 x 100 images.
    j, i = np.meshgrid(np.arange(100.), np.arange(100.), indexing='ij')
    cam = np.stack([(i - 50.) / f, -(j - 50.) / f, -np.ones_like(i)], -1)
    for k in (0, len(data.ids) - 1):
      rotation = np.array(meta['frames'][data.ids[k]]['transform_matrix'])[:3, :3]
      np.testing.assert_allclose(data.rays.directions[k], cam @ rotation.T, atol=1e-6)


def test_lego_first_n_split():
  data = load_dataset('train', blender_config(blender_split='first_n', n_input_views=2))
  assert data.ids == [0, 1] and data.images.shape == (2, 400, 400, 3)
