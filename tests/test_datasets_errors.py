"""Bad input for the LLFF and Blender loaders and the dispatcher: each error names the path or setting."""

import json
import os
import warnings
import zipfile

import numpy as np
import pytest

from conftest import H, N_LLFF, W
from internal.configs import Config
from internal.datasets import DatasetError, image_io, load_dataset


def llff(root, **kw):
  kw.setdefault('factor', 8)
  kw.setdefault('llff_scan', 'toy')
  return Config(dataset_loader='llff', data_dir=str(root), **kw)


def blender(root, **kw):
  kw.setdefault('blender_split', 'first_n')
  kw.setdefault('n_input_views', 3)
  kw.setdefault('blender_scene', 'toy')
  return Config(dataset_loader='blender', data_dir=str(root), **kw)


# ---------------------------------------------------------------- working toy scenes

def test_toy_llff_loads_and_falls_back_to_full_resolution(llff_root):
  with warnings.catch_warnings():
    warnings.simplefilter('error')  # images_8/ is there: nothing to say.
    data = load_dataset('train', llff(llff_root, n_input_views=3))
  assert data.ids == [1, 5, 9] and data.images.shape == (3, H, W, 3)
  os.rename(llff_root / 'toy' / 'images_8', llff_root / 'toy' / 'images')
  with warnings.catch_warnings():
    warnings.simplefilter('error')  # Only full-size images/: downsampling them is the layout's design.
    half = load_dataset('test', llff(llff_root, factor=2))   # No images_2/: images/ downsampled by 2.
  assert half.ids == [0, 8] and half.images.shape == (2, H // 2, W // 2, 3)
  full = image_io.read_image(str(llff_root / 'toy' / 'images' / 'img08.png'))
  np.testing.assert_allclose(half.images[1], full.reshape(3, 2, 4, 2, 3).mean((1, 3)), atol=1e-6)
  np.testing.assert_allclose(np.linalg.inv(half.pixtocams[0])[0, 0], 50. / 2., rtol=1e-6)
  os.rename(llff_root / 'toy' / 'images', llff_root / 'toy' / 'images_2')
  with pytest.warns(UserWarning, match=r"^'.*toy/images_4' does not exist \(downsampling factor 4\); "
                                       r"building the images from '.*toy/images_2', downsampled by 2$"):
    quarter = load_dataset('test', llff(llff_root, factor=4))   # A made-ahead images_2/ resized: said.
  assert quarter.images.shape == (2, H // 2, W // 2, 3)


def test_eval_factor_downsamples_test_views_only(blender_root):
  test = load_dataset('test', blender(blender_root, eval_factor=2, downsample_mode='area'))
  train = load_dataset('train', blender(blender_root, eval_factor=2, downsample_mode='area'))
  assert test.images.shape == (2, 4, 4, 3) and train.images.shape == (3, 8, 8, 3)


def test_blender_missing_test_images_and_allow_flag(blender_root):
  os.remove(blender_root / 'toy' / 'test' / 'r_8.png')
  with pytest.raises(DatasetError, match=r'r_8\.png.*allow_missing_test_views = True'):
    load_dataset('test', blender(blender_root))
  assert load_dataset('test', blender(blender_root, allow_missing_test_views=True)).ids == [0]


# ---------------------------------------------------------------- bad input

@pytest.mark.parametrize('make', [llff, blender])
def test_data_folder_missing(tmp_path, make):
  with pytest.raises(FileNotFoundError, match=r"Config.data_dir = .*missing.*does not exist"):
    load_dataset('train', make(tmp_path / 'missing'))


def _capture(root, **kw):
  return Config(dataset_loader='capture', data_dir=str(root), **kw)


def _generated(root, **kw):
  return Config(dataset_loader='generated', data_dir=str(root), **kw)


@pytest.mark.parametrize('make', [llff, blender, _capture, _generated])
@pytest.mark.parametrize('name, archive', [('fern.zip', True), ('notes.txt', False)])
def test_a_data_dir_that_is_a_file_is_named_a_file(tmp_path, make, name, archive):
  path = tmp_path / name
  if archive:
    with zipfile.ZipFile(path, 'w') as f:
      f.writestr('fern/poses_bounds.npy', b'')
  else:
    path.write_text('text')
  with pytest.raises(DatasetError, match=rf"^Config.data_dir = '.*{name}' is a file; expected a folder holding") as err:
    load_dataset('train', make(path))
  assert ('it is an archive: unpack it' in str(err.value)) == archive and not isinstance(err.value, FileNotFoundError)


def test_a_packed_data_dir_that_is_a_folder_is_named_a_folder(tmp_path):
  with pytest.raises(DatasetError, match=r"Config.data_dir = '.*' is a folder; Config.dataset_loader = 'packed' "
                                         r"expects the .npz file"):
    load_dataset('train', Config(dataset_loader='packed', data_dir=str(tmp_path)))


def test_scene_not_found_lists_scenes(llff_root, blender_root):
  with pytest.raises(DatasetError, match=r"Config.llff_scan = 'fern'.*\['toy'\]"):
    load_dataset('train', llff(llff_root, llff_scan='fern'))
  with pytest.raises(DatasetError, match=r"Config.blender_scene = 'lego'.*\['toy'\]"):
    load_dataset('train', blender(blender_root, blender_scene='lego'))


def test_llff_image_count_differs_from_pose_count(llff_root):
  os.remove(llff_root / 'toy' / 'images_8' / 'img03.png')
  with pytest.raises(DatasetError, match=r'9 images in .*images_8.* but 10 poses in .*poses_bounds\.npy'):
    load_dataset('train', llff(llff_root, n_input_views=3))


def test_llff_poses_bounds_wrong_shape_or_unreadable(llff_root):
  path = llff_root / 'toy' / 'poses_bounds.npy'
  np.save(path, np.zeros((N_LLFF, 15)))
  with pytest.raises(DatasetError, match=r'poses_bounds\.npy.*shape \(10, 15\).*\[N, 17\]'):
    load_dataset('train', llff(llff_root, n_input_views=3))
  path.write_bytes(b'garbage')
  with pytest.raises(DatasetError, match=r'cannot read camera file .*poses_bounds\.npy'):
    load_dataset('train', llff(llff_root, n_input_views=3))
  os.remove(path)
  with pytest.raises(FileNotFoundError, match=r'poses_bounds\.npy'):
    load_dataset('train', llff(llff_root, n_input_views=3))


def test_llff_factor_folder_missing(llff_root):
  with pytest.raises(FileNotFoundError, match=r"images_4.*Config.factor = 4.*\['images_8'\]"):
    load_dataset('train', llff(llff_root, factor=4, n_input_views=3))


@pytest.mark.parametrize('content', [b'not an image at all', None])
def test_truncated_or_non_image_files(llff_root, blender_root, content):
  for path, config in ((llff_root / 'toy' / 'images_8' / 'img01.png', llff(llff_root, n_input_views=3)),
                       (blender_root / 'toy' / 'train' / 'r_1.png', blender(blender_root))):
    path.write_bytes(content if content is not None else path.read_bytes()[:60])
    with pytest.raises(DatasetError, match=f'cannot read image .*{path.name}'):
      load_dataset('train', config)


def test_too_many_input_views(llff_root, blender_root):
  with pytest.raises(DatasetError, match=r'n_input_views = 9 exceeds the 8 LLFF training views'):
    load_dataset('train', llff(llff_root, n_input_views=9))
  with pytest.raises(DatasetError, match=r'n_input_views = 4 exceeds the 3 training views'):
    load_dataset('train', blender(blender_root, n_input_views=4))
  with pytest.raises(DatasetError, match=r"blender_split = 'dietnerf' needs train frames.*has 3 frames"):
    load_dataset('train', blender(blender_root, blender_split='dietnerf', n_input_views=1))


def test_unknown_split_loader_and_option_names(llff_root, blender_root):
  with pytest.raises(DatasetError, match=r"unknown split 'val'.*\['train', 'test'\]"):
    load_dataset('val', llff(llff_root))
  with pytest.raises(DatasetError, match='Config.dataset_loader'):
    load_dataset('train', Config(dataset_loader='nerfstudio'))
  with pytest.raises(DatasetError, match='Config.blender_split'):
    load_dataset('train', blender(blender_root, blender_split='random'))
  with pytest.raises(DatasetError, match='Config.downsample_mode'):
    load_dataset('train', blender(blender_root, factor=2, downsample_mode='cubic'))
  with pytest.raises(DatasetError, match='Config.llffhold'):
    load_dataset('train', llff(llff_root, llffhold=0))


def test_blender_unreadable_transforms(blender_root):
  path = blender_root / 'toy' / 'transforms_train.json'
  path.write_text('{"frames": []}')
  with pytest.raises(DatasetError, match=r"cannot read camera file .*transforms_train\.json.*camera_angle_x"):
    load_dataset('train', blender(blender_root))
  path.write_text('{not json')
  with pytest.raises(DatasetError, match=r'transforms_train\.json'):
    load_dataset('train', blender(blender_root))
  path.write_text(json.dumps({'camera_angle_x': .7, 'frames': [{'file_path': 'a', 'transform_matrix': [[1]]}]}))
  with pytest.raises(DatasetError, match=r'transforms_train\.json.*4x4'):
    load_dataset('train', blender(blender_root))
  os.remove(path)
  with pytest.raises(FileNotFoundError, match=r'transforms_train\.json'):
    load_dataset('train', blender(blender_root))
