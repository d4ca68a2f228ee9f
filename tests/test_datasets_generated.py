"""The generated scene: determinism, exact depth/masks through the real loaders, scene-folder safety."""

import dataclasses
import filecmp
import json
import os
import warnings

import numpy as np
import pytest
from scipy import ndimage

from internal.configs import Config
from internal.datasets import (DatasetError, image_io, llff, load_dataset, loader, make_batcher, scene_generator,
                               random_poses, render_path_rays)


def gen_config(path, rig, **kw):
  return Config(dataset_loader='generated', data_dir=str(path), generated_rig=rig, **kw)


@pytest.fixture(scope='module')
def scenes(tmp_path_factory):
  root = tmp_path_factory.mktemp('generated')
  out = {}
  for rig in ('object', 'forward'):
    config = gen_config(root / rig, rig, n_input_views=9)
    out[rig] = (root / rig, load_dataset('train', config), load_dataset('test', config, ground_truth=True))
  return out


# ---------------------------------------------------------------- an independent ray caster for checking

def first_hit(solid, o, d):
  """[R] ray parameter of the first intersection with one solid of scene.json (inf: none)."""
  if solid['shape'] == 'sphere':
    c, r = np.array(solid['centre']), solid['radius']
    out = np.full(len(o), np.inf)
    for k in range(len(o)):   # Roots of |o + t d - c|^2 = r^2 with numpy's polynomial solver.
      rel = o[k] - c
      roots = np.roots([d[k] @ d[k], 2. * rel @ d[k], rel @ rel - r * r])
      real = roots[(np.abs(roots.imag) < 1e-9) & (roots.real > 0)].real
      out[k] = real.min() if real.size else np.inf
    return out
  if solid['shape'] == 'plane':
    n = np.array(solid['normal'])
    t = (solid['offset'] - o @ n) / (d @ n)
    p = o + t[:, None] * d
    ok = t > 0
    if solid['radius'] is not None:
      ok &= np.linalg.norm(p - solid['offset'] * n, axis=-1) <= solid['radius']
    return np.where(ok, t, np.inf)
  rot, half, c = np.array(solid['rotation']), np.array(solid['half']), np.array(solid['centre'])
  best = np.full(len(o), np.inf)   # Six face rectangles, each intersected as a bounded plane.
  for axis in range(3):
    for sign in (-1., 1.):
      n = rot[:, axis] * sign
      t = (n @ c + half[axis] - o @ n) / (d @ n)
      local = (o + t[:, None] * d - c) @ rot
      inside = (np.abs(local) <= half + 1e-9).all(-1) & (t > 0)
      best = np.where(inside & (t < best), t, best)
  return best


def cast(scene, o, d):
  """(t [R] of the nearest solid, kind [R] of it or '') for rays o, d [R,3]."""
  ts = np.stack([first_hit(s, o, d) for s in scene['solids']])
  kinds = np.array([s['kind'] for s in scene['solids']] + [''])
  nearest = np.where(np.isfinite(ts.min(0)), ts.argmin(0), len(scene['solids']))
  return ts.min(0), kinds[nearest]


def sample_pixels(data, n, seed):
  rng = np.random.default_rng(seed)
  return rng.integers(data.images.shape[0], size=n), rng.integers(data.height, size=n), \
      rng.integers(data.width, size=n)


# ---------------------------------------------------------------- tests

def test_generated_views_and_shapes(scenes):
  _, train, test = scenes['object']
  assert train.ids == list(range(9)) and test.ids == list(range(8))
  assert train.images.shape == (9, 64, 80, 3) and test.depths.shape == (8, 64, 80)
  assert test.object_masks.shape == (8, 64, 80) and test.masks is None
  assert test.near == 2. and test.far == 6. and train.name == 'generated/object'
  hit = test.depths > 0
  assert 2. < test.depths[hit].min() and test.depths.max() < 6.    # Inside the default near/far.
  far_from_hits = ~ndimage.binary_dilation(hit, structure=np.ones((1, 3, 3), bool))
  assert far_from_hits.mean() > .2
  np.testing.assert_array_equal(test.images[far_from_hits], 1.)      # White background where nothing is hit.
  _, train, test = scenes['forward']
  assert train.ids == [1, 3, 5, 7, 10, 12, 14, 17, 19] and test.ids == [0, 8, 16]
  assert train.images.shape == (9, 64, 80, 3) and (test.depths > 0).all()


def test_object_rig_depth_is_the_analytic_intersection(scenes):
  """Loader ray o + depth*d hits the surface: depth equals an independent analytic cast of that ray."""
  path, _, test = scenes['object']
  scene = json.loads((path / 'scene.json').read_text())
  n, r, c = sample_pixels(test, 400, 0)
  o, d = test.rays.origins[n, r, c].astype(np.float64), test.rays.directions[n, r, c].astype(np.float64)
  t, kind = cast(scene, o, d)
  depth = test.depths[n, r, c]
  hit = np.isfinite(t)
  assert hit.sum() > 150 and (~hit).sum() > 20
  np.testing.assert_allclose(depth[hit], t[hit], rtol=1e-5)
  assert (depth[~hit] == 0).all()
  full = test.object_masks[n, r, c] == 1.
  assert full.sum() > 20 and (kind[full] == 'object').all()
  assert (kind[test.object_masks[n, r, c] == 0.] != 'object').all()


def test_forward_rig_depth_exact_in_file_and_loader_worlds(scenes):
  path, _, test = scenes['forward']
  scene = json.loads((path / 'scene.json').read_text())
  pb = np.load(path / 'poses_bounds.npy')
  pose, (h, w, f) = pb[0, :15].reshape(3, 5)[:, :4], pb[0, :15].reshape(3, 5)[:, 4]
  depth_file = np.load(path / 'depth' / 'images' / 'image000.npy')
  rng = np.random.default_rng(1)
  r, c = rng.integers(64, size=300), rng.integers(80, size=300)
  cam = np.stack([(c + .5 - w / 2) / f, -(r + .5 - h / 2) / f, -np.ones(300)], -1)
  right, up, back = pose[:, 1], -pose[:, 0], pose[:, 2]
  d = cam[:, :1] * right + cam[:, 1:2] * up + cam[:, 2:] * back
  t, _ = cast(scene, np.broadcast_to(pose[:, 3], d.shape), d)
  np.testing.assert_allclose(depth_file[r, c], t, rtol=1e-5)
  # Loader world (scaled by 1/(0.75 min bound), recentered): the depth point lies on the NDC ray.
  np.testing.assert_allclose(test.depths[0], depth_file / (.75 * pb[:, 15:].min()), rtol=1e-5)
  focal = f
  point = test.camtoworlds[0, :, 3] + test.depths[0, r, c, None] * test.rays.viewdirs[0, r, c]
  ndc = np.stack([-2 * focal / w * point[:, 0] / point[:, 2], -2 * focal / h * point[:, 1] / point[:, 2],
                  1 + 2 / point[:, 2]], -1)
  off = np.cross(ndc - test.rays.origins[0, r, c], test.rays.directions[0, r, c])
  assert np.abs(off).max() < 1e-4


def test_write_scene_is_deterministic_and_seeded(tmp_path):
  scene_generator.write_scene(str(tmp_path / 'a'), 'forward', seed=3, height=16, width=20)
  scene_generator.write_scene(str(tmp_path / 'b'), 'forward', seed=3, height=16, width=20)
  scene_generator.write_scene(str(tmp_path / 'c'), 'forward', seed=4, height=16, width=20)
  files = sorted(str(p.relative_to(tmp_path / 'a')) for p in (tmp_path / 'a').rglob('*') if p.is_file())
  assert len(files) == 1 + 1 + 3 * 20
  match, mismatch, errors = filecmp.cmpfiles(tmp_path / 'a', tmp_path / 'b', files, shallow=False)
  assert len(match) == len(files) and not mismatch and not errors
  _, mismatch, _ = filecmp.cmpfiles(tmp_path / 'a', tmp_path / 'c', files, shallow=False)
  assert 'scene.json' in mismatch and 'images/image000.png' in mismatch


def test_write_scene_any_size(tmp_path):
  scene_generator.write_scene(str(tmp_path / 'big'), 'object', height=30, width=50)
  data = load_dataset('test', gen_config(tmp_path / 'big', 'object', generated_size=(30, 50), n_input_views=2))
  assert data.images.shape == (8, 30, 50, 3)


def test_existing_scene_is_reused_and_a_different_one_refused(tmp_path, scenes):
  path, train, _ = scenes['object']
  stamp = os.path.getmtime(path / 'scene.json')
  again = load_dataset('train', gen_config(path, 'object', n_input_views=9))
  np.testing.assert_array_equal(again.images, train.images)
  assert os.path.getmtime(path / 'scene.json') == stamp
  with pytest.raises(DatasetError, match=r"holds a different generated scene.*'rig': 'object'.*'rig': 'forward'"):
    load_dataset('train', gen_config(path, 'forward'))
  with pytest.raises(DatasetError, match='different generated scene'):
    load_dataset('train', gen_config(path, 'object', generated_size=(32, 40)))
  (tmp_path / 'other').mkdir()
  (tmp_path / 'other' / 'notes.txt').write_text('mine')
  with pytest.raises(DatasetError, match='holds no generated scene'):
    load_dataset('train', gen_config(tmp_path / 'other', 'object'))
  (tmp_path / 'empty').mkdir()
  assert load_dataset('train', gen_config(tmp_path / 'empty', 'forward', n_input_views=3)).ids == [1, 10, 19]


def test_generated_unknown_rig(tmp_path):
  with pytest.raises(DatasetError, match='generated_rig'):
    load_dataset('train', gen_config(tmp_path / 'x', 'orbit'))


def test_generated_render_path_and_batches(scenes):
  path, train, _ = scenes['object']
  rays = render_path_rays(gen_config(path, 'object', render_path_frames=5))
  assert rays.origins.shape == (5, 64, 80, 3)
  centre_dirs = rays.directions[:, 32, 40].astype(np.float64)
  to_origin = -rays.origins[:, 32, 40]
  cos = (centre_dirs * to_origin).sum(-1) / np.linalg.norm(centre_dirs, axis=-1) / np.linalg.norm(to_origin, axis=-1)
  assert (cos > .999).all()   # The orbit faces the origin.
  batch = make_batcher(train, Config(batch_size=64))(0)
  assert batch.rgb.shape == (64, 3) and batch.rays.near.shape == (64, 1)


@pytest.mark.parametrize('rig', ['object', 'forward'])
def test_depths_and_object_masks_are_read_only_when_asked(scenes, rig, monkeypatch):
  path = scenes[rig][0]
  opened = []
  np_load, read_image = np.load, image_io.read_image
  monkeypatch.setattr(np, 'load', lambda f, *a, **k: opened.append(str(f)) or np_load(f, *a, **k))
  monkeypatch.setattr(image_io, 'read_image', lambda f, *a, **k: opened.append(str(f)) or read_image(f, *a, **k))
  ground_truth = lambda: [f for f in opened if f'{os.sep}depth{os.sep}' in f or f'{os.sep}mask{os.sep}' in f]
  for split in ('train', 'test'):
    data = load_dataset(split, gen_config(path, rig, n_input_views=9))
    assert data.depths is None and data.object_masks is None and opened and not ground_truth()
  data = load_dataset('test', gen_config(path, rig, n_input_views=9), ground_truth=True)
  assert len(ground_truth()) == 2 * len(data.ids)  # One depth .npy and one mask .png per test view.
  np.testing.assert_array_equal(data.depths, scenes[rig][2].depths)


def test_forward_rig_random_poses_are_llffs_of_its_poses_file(scenes):
  path, train, _ = scenes['forward']
  config = gen_config(path, 'forward', n_input_views=9, n_random_poses=20, regnerf_fix_released_bugs=True)
  cameras = loader.random_pose_cameras(train, config, np.random.default_rng(3))
  raw = np.load(path / 'poses_bounds.npy')
  assert train.space.ndc_focal == raw[0, 14]  # Generated at factor 1: the file's focal, the space the poses share.
  np.testing.assert_allclose(cameras.pixtocams, np.broadcast_to(train.pixtocams[0], (20, 3, 3)), rtol=1e-6)
  c2w, bounds, _ = llff.process_poses(raw)
  np.testing.assert_array_equal(cameras.camtoworlds, random_poses.llff_random_poses(c2w, bounds, 20,
                                                                                    np.random.default_rng(3), False))
  tv = dataclasses.replace(config, depth_tvnorm_loss_mult=.1, batch_size=64, batch_size_random=128)
  patches = make_batcher(train, tv)(2).patch_rays
  assert patches.origins.shape == (2, 8, 8, 3) and (patches.near == 0.).all() and (patches.far == 1.).all()


def test_object_rig_has_no_random_poses(scenes):
  path, train, _ = scenes['object']
  config = gen_config(path, 'object', n_input_views=9, depth_tvnorm_loss_mult=.1)
  with pytest.raises(ValueError, match=r"Config.dataset_loader = 'generated' scene has none"):
    make_batcher(train, config)


def test_the_forward_rig_resizes_its_full_size_images_without_a_word(scenes):
  path, _, _ = scenes['forward']
  with warnings.catch_warnings():
    warnings.simplefilter('error')  # Unlike an LLFF scene's missing images_4/, this is the layout's design.
    data = load_dataset('train', gen_config(path, 'forward', n_input_views=9, factor=4))
    render_path_rays(gen_config(path, 'forward', factor=4, render_path_frames=2))
  assert data.images.shape[1:3] == (64 // 4, 80 // 4) and not os.path.isdir(path / 'images_4')
