"""DTU on-disk layouts written by the tests: RegNeRF (Rectified + cal18 + idrmasks) versus IDR/NeuS, and errors."""

import os
import pathlib

import numpy as np
import pytest
from PIL import Image

from internal.configs import Config
from internal.datasets import DatasetError, load_dataset
from internal.datasets import dtu

DATA = pathlib.Path(__file__).resolve().parents[2] / 'shared' / 'data'
SCAN24_CAMERAS = DATA / 'dtu' / 'dtu_scan24' / 'cameras_sphere.npz'
IDS = sorted(dtu.TRAIN_IDS + dtu.TEST_IDS)
H, W = 48, 64


def synthetic_projections():
  """49 projection matrices s*K[R|t] of OpenCV cameras on a sphere facing the origin (s > 0 varies)."""
  rng = np.random.default_rng(0)
  k = np.array([[1000., .3, 820.], [0., 990., 610.], [0., 0., 1.]])
  out = []
  for i in range(49):
    theta, phi = 2. * np.pi * i / 49., .4 + .5 * (i % 7) / 7.
    centre = 3. * np.array([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), -np.cos(phi)])
    z = -centre / np.linalg.norm(centre)
    x = np.cross([0., 0., 1.], z)
    x /= np.linalg.norm(x)
    rot = np.stack([x, np.cross(z, x), z])
    out.append(rng.uniform(.5, 2.) * k @ np.concatenate([rot, -rot @ centre[:, None]], 1))
  return np.stack(out)


def projections(source):
  if source == 'synthetic':
    return synthetic_projections()
  if not SCAN24_CAMERAS.is_file():
    pytest.skip(f'real scan24 cameras absent: {SCAN24_CAMERAS} does not exist')
  with np.load(SCAN24_CAMERAS) as cams:
    return np.stack([cams[f'world_mat_{i}'][:3] for i in range(49)])


def tiny_image(i):
  return np.random.default_rng(100 + i).integers(0, 256, (H, W, 3), dtype=np.uint8)


def tiny_mask(i):
  """Foreground 255 block, an anti-aliased 200 band (background by the == 255 rule), zeros elsewhere."""
  mask = np.zeros((H, W, 3), np.uint8)
  mask[8 + i % 5:30, 10:40 + i % 7] = 255
  mask[30:33, 10:40] = 200
  return mask


def save(path, array):
  os.makedirs(os.path.dirname(path), exist_ok=True)
  Image.fromarray(array).save(path)


def write_idr(root, scan, projs, image_dir='image'):
  """IDR/NeuS layout: <root>/<scan>/cameras_sphere.npz, image/NNNNNN.png, mask/NNN.png."""
  folder = os.path.join(root, scan)
  os.makedirs(folder, exist_ok=True)
  mats = {f'world_mat_{i}': np.concatenate([p, [[0., 0., 0., 1.]]]) for i, p in enumerate(projs)}
  np.savez(os.path.join(folder, 'cameras_sphere.npz'), **mats)
  for i in IDS:
    save(os.path.join(folder, image_dir, f'{i:06d}.png'), tiny_image(i))
    save(os.path.join(folder, 'mask', f'{i:03d}.png'), tiny_mask(i))
  return folder


def write_regnerf(root, scan, projs, mask_subdir=''):
  """RegNeRF layout: <root>/Rectified/<scan>/rect_XXX_3_r5000.png, <root>/Calibration/cal18/pos_XXX.txt, idrmasks."""
  for i, p in enumerate(projs):
    os.makedirs(os.path.join(root, 'Calibration', 'cal18'), exist_ok=True)
    np.savetxt(os.path.join(root, 'Calibration', 'cal18', f'pos_{i + 1:03d}.txt'), p)
  number = dtu.scan_number(scan)
  for i in IDS:
    save(os.path.join(root, 'Rectified', scan, f'rect_{i + 1:03d}_3_r5000.png'), tiny_image(i))
    save(os.path.join(root, 'idrmasks', f'scan{number}', mask_subdir, f'{i:03d}.png'), tiny_mask(i))


def config(data_dir, scan, **kw):
  return Config(dataset_loader='dtu', data_dir=str(data_dir), dtu_scan=scan, factor=4, near=.5, far=3.5, **kw)


def assert_same(a, b):
  assert a.ids == b.ids and a.height == b.height and a.width == b.width
  np.testing.assert_array_equal(a.images, b.images)
  np.testing.assert_allclose(a.camtoworlds, b.camtoworlds, rtol=1e-6, atol=1e-6)
  np.testing.assert_allclose(a.pixtocams, b.pixtocams, rtol=1e-6, atol=1e-9)
  for x, y in zip(a.rays, b.rays):
    np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5)
  if a.masks is None:
    assert b.masks is None
  else:
    np.testing.assert_array_equal(a.masks, b.masks)


@pytest.mark.parametrize('source', ['synthetic', 'scan24'])
def test_regnerf_layout_gives_the_idr_cameras(tmp_path, source):
  projs = projections(source)
  write_idr(tmp_path / 'idr', 'scan24', projs)
  write_regnerf(tmp_path, 'scan24', projs)
  for split in ('train', 'test'):
    idr = load_dataset(split, config(tmp_path / 'idr', 'scan24', n_input_views=6))
    reg = load_dataset(split, config(tmp_path / 'Rectified', 'scan24', n_input_views=6,
                                     dtu_mask_path=str(tmp_path / 'idrmasks')))
    assert_same(idr, reg)
  assert idr.ids == list(dtu.TEST_IDS) and idr.images.shape == (25, 12, 16, 3)
  binary = (tiny_mask(1) == 255).astype(np.float32)
  expected = (binary[1::4, 1::4] + binary[2::4, 1::4] + binary[1::4, 2::4] + binary[2::4, 2::4]) / 4.
  np.testing.assert_array_equal(reg.masks[0], expected)


def test_decomposed_cameras_match_the_generating_cameras(tmp_path):
  """Normalised c2w and K from P agree with the generating K, R, C up to the recentering similarity."""
  projs = synthetic_projections()
  write_idr(tmp_path, 'scan24', projs)
  data = load_dataset('train', config(tmp_path, 'scan24', n_input_views=9))
  k = np.linalg.inv(data.pixtocams.astype(np.float64))
  np.testing.assert_allclose(k[0], np.diag([.25, .25, 1.]) @ np.array([[1000., .3, 820.], [0., 990., 610.],
                                                                         [0., 0., 1.]]), rtol=1e-5, atol=1e-6)
  # Camera centres (null vectors of P) map to the loader's centres by one similarity: distance ratios agree.
  world = [np.linalg.svd(projs[i])[2][-1] for i in data.ids]
  centres = np.array([c[:3] / c[3] for c in world])
  got = data.camtoworlds[:, :, 3].astype(np.float64)
  ratios = np.linalg.norm(got[1:] - got[0], axis=-1) / np.linalg.norm(centres[1:] - centres[0], axis=-1)
  np.testing.assert_allclose(ratios, ratios[0], rtol=1e-5)


def test_dtu_scan_named_like_the_shared_folder(tmp_path):
  """dtu_scan='dtu_scan24' finds <data_dir>/dtu_scan24 and the idrmasks folder scan24."""
  projs = synthetic_projections()
  write_regnerf(tmp_path, 'dtu_scan24', projs)
  data = load_dataset('test', config(tmp_path / 'Rectified', 'dtu_scan24',
                                     dtu_mask_path=str(tmp_path / 'idrmasks')))
  assert data.masks.shape == (25, 12, 16, 3) and data.name == 'dtu/dtu_scan24'


def test_idrmasks_mask_subfolder_for_idr_scans(tmp_path):
  projs = synthetic_projections()
  write_regnerf(tmp_path, 'scan40', projs, mask_subdir='mask')
  data = load_dataset('test', config(tmp_path / 'Rectified', 'scan40', dtu_mask_path=str(tmp_path / 'idrmasks')))
  assert data.masks.shape == (25, 12, 16, 3)
  write_regnerf(tmp_path / 'flat', 'scan40', projs)  # Without the mask/ subfolder: found as well.
  flat = load_dataset('test', config(tmp_path / 'flat' / 'Rectified', 'scan40',
                                     dtu_mask_path=str(tmp_path / 'flat' / 'idrmasks')))
  np.testing.assert_array_equal(flat.masks, data.masks)
  with pytest.raises(DatasetError, match=r"any of \[.*scan40/mask', .*scan40'\]"):
    load_dataset('test', config(tmp_path / 'flat' / 'Rectified', 'scan40', dtu_mask_path=str(tmp_path)))


def test_idr_layout_with_idrmasks_and_images_folder(tmp_path):
  projs = synthetic_projections()
  write_idr(tmp_path, 'scan24', projs, image_dir='images')
  write_regnerf(tmp_path, 'scan24', projs)
  own = load_dataset('test', config(tmp_path, 'scan24'))
  other = load_dataset('test', config(tmp_path, 'scan24', dtu_mask_path=str(tmp_path / 'idrmasks')))
  assert_same(own, other)


def test_layout_detection_and_forcing(tmp_path):
  projs = synthetic_projections()
  write_regnerf(tmp_path, 'scan24', projs)
  idr_root = tmp_path / 'other' / 'idr'
  write_idr(idr_root, 'scan24', projs)
  assert dtu.detect_layout(str(tmp_path / 'Rectified' / 'scan24'), 'auto') == 'regnerf'
  assert dtu.detect_layout(str(idr_root / 'scan24'), 'auto') == 'idr'
  with pytest.raises(DatasetError, match='cameras_sphere.npz'):
    load_dataset('train', config(tmp_path / 'Rectified', 'scan24', dtu_layout='idr'))
  with pytest.raises(DatasetError, match=r'Calibration/cal18/pos_001\.txt'):
    load_dataset('train', config(idr_root, 'scan24', dtu_layout='regnerf'))
  with pytest.raises(DatasetError, match='dtu_layout'):
    load_dataset('train', config(idr_root, 'scan24', dtu_layout='neus'))
  (tmp_path / 'empty' / 'scan1').mkdir(parents=True)
  with pytest.raises(DatasetError, match='cannot tell the DTU layout'):
    load_dataset('train', config(tmp_path / 'empty', 'scan1'))


# ---------------------------------------------------------------- DTU bad input

@pytest.fixture
def idr_scan(tmp_path):
  write_idr(tmp_path, 'scan24', synthetic_projections())
  return tmp_path


def test_dtu_data_dir_and_scan_missing(tmp_path, idr_scan):
  with pytest.raises(FileNotFoundError, match=r"Config.data_dir = .*nowhere"):
    load_dataset('train', config(tmp_path / 'nowhere', 'scan24'))
  with pytest.raises(DatasetError, match=r"Config.dtu_scan = 'scan8'.*\['scan24'\]"):
    load_dataset('train', config(idr_scan, 'scan8'))


def test_dtu_missing_test_image_and_allow_flag(idr_scan):
  os.remove(idr_scan / 'scan24' / 'image' / '000002.png')
  with pytest.raises(DatasetError, match=r'000002\.png.*allow_missing_test_views = True'):
    load_dataset('test', config(idr_scan, 'scan24'))
  data = load_dataset('test', config(idr_scan, 'scan24', allow_missing_test_views=True))
  assert data.ids == [i for i in dtu.TEST_IDS if i != 2] and data.masks.shape[0] == 24


def test_dtu_missing_train_image(idr_scan):
  os.remove(idr_scan / 'scan24' / 'image' / '000025.png')
  with pytest.raises(FileNotFoundError, match=r'training image.*000025\.png'):
    load_dataset('train', config(idr_scan, 'scan24', allow_missing_test_views=True))


def test_dtu_mask_missing_for_a_test_view(idr_scan):
  os.remove(idr_scan / 'scan24' / 'mask' / '047.png')
  with pytest.raises(DatasetError, match=r'mask.*047\.png'):
    load_dataset('test', config(idr_scan, 'scan24'))


def test_dtu_regnerf_layout_needs_mask_path_for_test(tmp_path):
  write_regnerf(tmp_path, 'scan24', synthetic_projections())
  with pytest.raises(DatasetError, match='dtu_mask_path'):
    load_dataset('test', config(tmp_path / 'Rectified', 'scan24'))


def test_dtu_too_many_views(idr_scan):
  with pytest.raises(DatasetError, match='n_input_views = 10 exceeds the 9'):
    load_dataset('train', config(idr_scan, 'scan24', n_input_views=10))


def test_dtu_unreadable_cameras(tmp_path, idr_scan):
  (idr_scan / 'scan24' / 'cameras_sphere.npz').write_bytes(b'not a zip file')
  with pytest.raises(DatasetError, match=r'cannot read camera file .*cameras_sphere\.npz'):
    load_dataset('train', config(idr_scan, 'scan24'))
  write_regnerf(tmp_path / 'reg', 'scan24', synthetic_projections())
  (tmp_path / 'reg' / 'Calibration' / 'cal18' / 'pos_007.txt').write_text('1 2 3\nfoo bar\n')
  with pytest.raises(DatasetError, match=r'pos_007\.txt'):
    load_dataset('train', config(tmp_path / 'reg' / 'Rectified', 'scan24'))
  np.savetxt(tmp_path / 'reg' / 'Calibration' / 'cal18' / 'pos_007.txt', np.eye(3))
  with pytest.raises(DatasetError, match=r'pos_007\.txt.*3x4'):
    load_dataset('train', config(tmp_path / 'reg' / 'Rectified', 'scan24'))
  os.remove(tmp_path / 'reg' / 'Calibration' / 'cal18' / 'pos_007.txt')
  with pytest.raises(FileNotFoundError, match=r'pos_007\.txt'):
    load_dataset('train', config(tmp_path / 'reg' / 'Rectified', 'scan24'))


def test_dtu_truncated_and_non_image_files(idr_scan):
  path = idr_scan / 'scan24' / 'image' / '000025.png'
  path.write_bytes(path.read_bytes()[:200])
  with pytest.raises(DatasetError, match=r'cannot read image .*000025\.png.*truncated'):
    load_dataset('train', config(idr_scan, 'scan24', n_input_views=1))
  path.write_text('this is not an image')
  with pytest.raises(DatasetError, match=r'cannot read image .*000025\.png'):
    load_dataset('train', config(idr_scan, 'scan24', n_input_views=1))
