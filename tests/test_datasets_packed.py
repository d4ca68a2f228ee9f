"""Packed scenes (internal/datasets/packed.py, tools/pack_scene.py): packed and unpacked data are equal."""

import dataclasses

import numpy as np
import pytest

from conftest import SHARED_DATA
from internal.configs import Config
from internal.datasets import DatasetError, DatasetNotFoundError, load_dataset, loader, packed, render_path_rays
from tools import pack_scene


def generated_config(tmp_path, rig):
  return Config(dataset_loader='generated', data_dir=str(tmp_path / f'scene_{rig}'), generated_rig=rig,
                generated_size=(12, 16), n_input_views=3, render_path_frames=2,
                near=0. if rig == 'forward' else 2., far=1. if rig == 'forward' else 6.)


def assert_same(a, b):
  """Every Dataset field equal: rays bitwise, images/masks/ground truth exactly, ids, sizes, names."""
  for x, y in zip(a.rays, b.rays):
    assert x.dtype == y.dtype == np.float32
    np.testing.assert_array_equal(x, y)
  for name in ('images', 'masks', 'depths', 'object_masks', 'camtoworlds', 'pixtocams'):
    x, y = getattr(a, name), getattr(b, name)
    assert (x is None) == (y is None), name
    if x is not None:
      assert x.dtype == y.dtype, name
      np.testing.assert_array_equal(x, y, err_msg=name)
  assert (a.ids, a.height, a.width, a.near, a.far, a.split, a.name) == \
      (b.ids, b.height, b.width, b.near, b.far, b.split, b.name)
  assert packed.datasets_equal(a, b) == []


def pack_and_compare(config, out):
  """Packs config's scene to out and checks both splits and a short render path against the source."""
  datasets = pack_scene.pack(config, str(out))
  reloaded = dataclasses.replace(config, dataset_loader='packed', data_dir=str(out))
  for split, data in datasets.items():
    assert_same(load_dataset(split, reloaded), data)
  for x, y in zip(render_path_rays(reloaded), render_path_rays(config)):
    np.testing.assert_array_equal(x, y)
  return datasets, reloaded


@pytest.mark.parametrize('rig', ['object', 'forward'])
def test_generated_scene_packed_equals_unpacked(tmp_path, rig):
  config = generated_config(tmp_path, rig)
  datasets, reloaded = pack_and_compare(config, tmp_path / 'scene.npz')
  assert datasets['test'].depths is not None  # ground truth travels too
  with np.load(tmp_path / 'scene.npz') as f:
    assert f['train/images/index'].dtype == np.uint8  # 8-bit images at factor 1: 1 byte per value
    assert f['cameras/camtoworlds'].dtype == np.float64


def test_integer_pixel_rays_pack_and_are_checked(tmp_path):
  config = dataclasses.replace(generated_config(tmp_path, 'object'), pixel_offset=0.)
  datasets, reloaded = pack_and_compare(config, tmp_path / 'scene.npz')
  centred = load_dataset('train', dataclasses.replace(config, pixel_offset=.5))
  assert not np.allclose(datasets['train'].rays.directions, centred.rays.directions)
  with pytest.raises(DatasetError, match=r'Config.pixel_offset = 0.5, but .* made with Config.pixel_offset = 0.0'):
    load_dataset('train', dataclasses.replace(reloaded, pixel_offset=.5))


def test_settings_that_shaped_the_pack_are_checked(tmp_path):
  config = generated_config(tmp_path, 'object')
  pack_scene.pack(config, str(tmp_path / 'scene.npz'))
  reloaded = dataclasses.replace(config, dataset_loader='packed', data_dir=str(tmp_path / 'scene.npz'))
  for name, value in (('n_input_views', 2), ('factor', 2), ('near', 1.), ('generated_size', (16, 16)),
                      ('train_view_ids', (0, 1, 2)), ('test_view_ids', (4,))):
    with pytest.raises(DatasetError, match=rf'Config.{name} = .* was made with Config.{name} = '):
      load_dataset('train', dataclasses.replace(reloaded, **{name: value}))
  with pytest.raises(DatasetError, match='Config.render_factor'):
    render_path_rays(dataclasses.replace(reloaded, render_factor=2))
  frames = render_path_rays(dataclasses.replace(reloaded, render_path_frames=5))  # free: regenerated
  assert frames.origins.shape[:3] == (5, 12, 16)


def test_a_pack_made_with_explicit_views_is_refused_without_them(tmp_path):
  config = dataclasses.replace(generated_config(tmp_path, 'forward'), n_input_views=2, train_view_ids=(5, 3),
                               test_view_ids=(1,))
  pack_scene.pack(config, str(tmp_path / 'scene.npz'))
  reloaded = dataclasses.replace(config, dataset_loader='packed', data_dir=str(tmp_path / 'scene.npz'))
  assert load_dataset('train', reloaded).ids == [5, 3] and load_dataset('test', reloaded).ids == [1]
  with pytest.raises(DatasetError, match=r'Config.train_view_ids = \[\], but .* made with Config.train_view_ids = '
                                         r'\[5, 3\]'):
    load_dataset('train', dataclasses.replace(reloaded, train_view_ids=()))


def test_bad_pack_files(tmp_path):
  config = Config(dataset_loader='packed', data_dir=str(tmp_path / 'absent.npz'))
  with pytest.raises(DatasetNotFoundError, match='absent.npz'):
    load_dataset('train', config)
  np.savez(tmp_path / 'other.npz', x=np.zeros(3))
  with pytest.raises(DatasetError, match='is not a packed scene'):
    load_dataset('train', dataclasses.replace(config, data_dir=str(tmp_path / 'other.npz')))
  with pytest.raises(DatasetError, match="Config.dataset_loader = 'packed' scenes cannot be packed"):
    loader.pack_arrays(config, {})


def test_palette_coding_is_exact():
  rng = np.random.default_rng(0)
  few = (rng.integers(0, 200, (2, 5, 3)) / 255.).astype(np.float32)
  many = (rng.integers(0, 1021, (40, 50)) / 1020.).astype(np.float32)
  raw = rng.random(70000, dtype=np.float32)
  for values, key, dtype in ((few, 'a/index', np.uint8), (many, 'a/index', np.uint16), (raw, 'a', np.float32)):
    arrays = packed.encode('a', values)
    assert arrays[key].dtype == dtype
    decoded = packed.decode(arrays, 'a')
    assert decoded.dtype == np.float32
    np.testing.assert_array_equal(decoded, values)
  assert packed.decode({}, 'a') is None


def test_command_line(tmp_path, capsys):
  out = tmp_path / 'scene.npz'
  bindings = [f"Config.data_dir = '{tmp_path / 'scene'}'", 'Config.generated_size = (12, 16)']
  assert pack_scene.main(['--gin_bindings', *bindings, '--out', str(out)]) == 0
  assert 'train 2 views 12x16' in capsys.readouterr().out and out.is_file()  # The demo's 2 views.
  with pytest.raises(ValueError, match='expected a file name ending in .npz'):
    pack_scene.main(['--out', str(tmp_path / 'scene.zip')])
  out.write_bytes(b'the user\'s')
  with pytest.raises(FileExistsError, match='exists; delete it'):
    pack_scene.main(['--gin_bindings', *bindings, '--out', str(out)])
  assert out.read_bytes() == b'the user\'s'


@pytest.mark.skipif(not SHARED_DATA.is_dir(), reason=f'real scenes absent: {SHARED_DATA} does not exist')
@pytest.mark.parametrize('name,config', [
    ('fern', Config(dataset_loader='llff', data_dir=str(SHARED_DATA / 'llff'), llff_scan='fern', factor=8,
                    render_factor=8, n_input_views=3, near=0., far=1., render_path_frames=2)),
    ('dtu_scan24', Config(dataset_loader='dtu', data_dir=str(SHARED_DATA / 'dtu'), dtu_scan='dtu_scan24', factor=4,
                          render_factor=4, n_input_views=3, near=.5, far=3.5, white_background=False,
                          allow_missing_test_views=True, render_path_frames=2)),
])
def test_real_scene_packed_equals_unpacked(tmp_path, name, config):
  datasets, _ = pack_and_compare(config, tmp_path / f'{name}.npz')
  assert len(datasets['train'].ids) == 3
  if name == 'dtu_scan24':
    assert datasets['test'].masks is not None
  with np.load(tmp_path / f'{name}.npz') as f:
    n_cameras = 49 if name == 'dtu_scan24' else 20
    assert f['cameras/camtoworlds'].shape == (n_cameras, 3, 4) and f['cameras/pixtocams'].shape == (n_cameras, 3, 3)


def test_eval_files_a_pack_under_its_source(tmp_path):
  config = generated_config(tmp_path, 'object')
  pack_scene.pack(config, str(tmp_path / 'scene.npz'))
  reloaded = dataclasses.replace(config, dataset_loader='packed', data_dir=str(tmp_path / 'scene.npz'))
  assert loader.filed_as(reloaded) == loader.filed_as(config) == ('blender', 'generated_object')
