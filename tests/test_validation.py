"""Bad values are refused before any work: Config ranges and types, non-finite cameras, mixed image sizes."""

import dataclasses
import json
import os
import re

import jax
import numpy as np
import pytest

from conftest import noise, save_png
from internal import config_loader
from internal import configs
from internal import runs
from internal.models import freq_schedule
from internal.models import gaussians
from internal.evaluation import lpips
from internal.models import precision
from internal.models import sampling
from internal.training import train_step
from internal.datasets import batching, image_io, loader, packed, scene_generator
from internal.datasets import capture as capture_loader
from internal.datasets import blender as blender_lib
from internal.datasets import DatasetError, dtu, load_dataset
from test_checkpoints import tiny_config
from test_datasets_dtu_layouts import config as dtu_config, synthetic_projections, write_idr, write_regnerf
from test_datasets_errors import blender, llff


def _load(*bindings):
  return runs.bind_fresh([], list(bindings))


@pytest.mark.parametrize('binding, message', [
    ('Config.lr_init = 0.', r'Config.lr_init = 0.0; expected > 0'),
    ('Config.lr_init = -1e-3', r'Config.lr_init = -0.001; expected > 0'),
    ('Config.lr_final = 0.', r'Config.lr_final = 0.0; expected > 0'),
    ("Config.lr_init = float('nan')", 'Unable to parse|Config.lr_init'),
    ('Config.print_every = 0', r'Config.print_every = 0; expected a positive integer'),
    ('Config.checkpoint_every = 0', r'Config.checkpoint_every = 0; expected a positive integer'),
    ('Config.checkpoint_keep = 0', r'Config.checkpoint_keep = 0; expected a positive integer'),
    ('Config.near = 0.', r"Config.near = 0.0; expected > 0 for 'generated'"),
    ("Config.near = 'a'", r"Config.near = 'a'; expected float"),
    ('Config.max_steps = 1e5', r'Config.max_steps = 100000.0; expected int'),
    ('Config.nope = 1', "doesn't have a parameter named 'nope'"),
    ('Config.near = ', 'cannot parse the gin'),
    ('Config.factor = -2', r'^Config.factor = -2; expected >= 0'),
    ('Config.render_factor = -1', r'^Config.render_factor = -1; expected >= 0'),
    ('Config.eval_factor = 0', r'^Config.eval_factor = 0; expected a positive integer'),
    ('Config.curve_factor = 0', r'^Config.curve_factor = 0; expected a positive integer'),
    ('Config.generated_size = (0, 0)', r'^Config.generated_size = \(0, 0\); expected two positive integers'),
    ('Config.generated_size = (32,)', r'^Config.generated_size = \(32,\); expected two positive integers'),
    ('MipNerfModel.num_samples = 0', r'^MipNerfModel.num_samples = 0; expected an integer >= 1'),
    ('MipNerfModel.num_levels = 0', r'^MipNerfModel.num_levels = 0; expected an integer >= 1'),
    ('MLP.net_width = 0', r'^MLP.net_width = 0; expected an integer >= 1'),
    ('MLP.net_depth_viewdirs = 0', r'^MLP.net_depth_viewdirs = 0; expected an integer >= 1'),
    ("MLP.dense_kernel = 'triton'",
     r"^MLP.dense_kernel = 'triton'; expected one of \['xla', 'pallas', 'folded_bias'\]"),
    ('FusedDenseTiles.rows = 48', r'^FusedDenseTiles.rows = 48; expected a power of two >= 16'),
    ('FusedDenseTiles.chunk = 8', r'^FusedDenseTiles.chunk = 8; expected a power of two >= 16'),
    ('FusedDenseTiles.dw_rows = 40', r'^FusedDenseTiles.dw_rows = 40; expected a power of two >= 16'),
    ('FusedDenseTiles.num_warps = 0', r'^FusedDenseTiles.num_warps = 0; expected a power of two >= 1'),
    ('FusedDenseTiles.splits = 0', r'^FusedDenseTiles.splits = 0; expected an integer >= 1'),
])
def test_bad_settings_raise_value_errors_naming_them(binding, message):
  with pytest.raises(ValueError, match=message):
    _load(binding)


def test_the_fused_layer_refuses_an_activation_it_does_not_fuse():
  with pytest.raises(ValueError, match="^MLP.dense_kernel = 'pallas' fuses ReLU into the layer; MLP.net_activation "
                                       'is softplus, expected relu$'):
    _load("MLP.dense_kernel = 'pallas'", 'MLP.net_activation = @flax.nn.softplus')
  for relu in ('@relu_from_output', '@flax.nn.relu'):
    _load("MLP.dense_kernel = 'pallas'", f'MLP.net_activation = {relu}')
  with pytest.raises(ValueError, match="^MLP.dense_kernel = 'folded_bias' passes its ones column through ReLU; "
                                       'MLP.net_activation is softplus, expected relu$'):
    _load("MLP.dense_kernel = 'folded_bias'", 'MLP.net_activation = @flax.nn.softplus')
  with pytest.raises(ValueError, match='^FusedDensePasses.two_inputs = 1; expected True or False'):
    _load("MLP.dense_kernel = 'pallas'", 'FusedDensePasses.two_inputs = 1')


def test_the_fused_layer_refuses_several_devices(monkeypatch):
  monkeypatch.setattr(jax, 'device_count', lambda: 2)
  with pytest.raises(ValueError, match="^MLP.dense_kernel = 'pallas' runs on one device; this run has 2, "):
    _load("MLP.dense_kernel = 'pallas'")
  _load()  # XLA's layers split over any number.


def test_sizes_of_the_nerf_model_are_checked_when_it_is_the_model():
  for binding, minimum in (('NerfModel.num_coarse_samples = 0', 1), ('NerfModel.num_fine_samples = -1', 0),
                           ('NerfMLP.net_width = 0', 1), ('NerfMLP.net_width_viewdirs = 0', 1)):
    with pytest.raises(ValueError, match=rf'^{re.escape(binding)}; expected an integer >= {minimum}$'):
      _load("Config.model = 'nerf'", binding)
    _load(binding)  # mip-NeRF's run does not build the NeRF model.


@pytest.mark.parametrize('name, options', [
    ('Config.dataset_loader', loader.LOADERS), ('Config.dtu_layout', dtu.LAYOUTS),
    ('Config.blender_split', blender_lib.SPLIT_MODES), ('Config.downsample_mode', image_io.DOWNSAMPLE_MODES),
    ('Config.batching', batching.BATCHING_MODES), ('Config.freq_mask_layout', freq_schedule.LAYOUTS),
    ('Config.nonfinite_grad_policy', train_step.NONFINITE_POLICIES), ('Config.lpips_input_range', lpips.INPUT_RANGES),
    ('Config.generated_rig', scene_generator.RIGS), ('Config.precision', precision.CHOICES),
    ('Config.capture_rig', capture_loader.RIGS),
    ('MipNerfModel.ray_shape', gaussians.RAY_SHAPES), ('MipNerfModel.pdf_padding', sampling.PDF_PADDINGS)])
def test_option_settings_use_the_list_of_the_module_that_implements_them(name, options):
  with pytest.raises(ValueError, match=re.escape(f"{name} = 'nope'; expected one of {list(options)}")):
    _load(f"{name} = 'nope'")
  for option in options[1:]:  # Every listed option passes validation (the first is the default).
    if name != 'Config.dataset_loader':  # The loaders' own settings (near > 0 ...) are tested apart.
      _load(f'{name} = {option!r}')


def test_non_finite_near_is_refused():
  with pytest.raises(ValueError, match='Config.near = nan; expected a finite number'):
    config_loader.validate(configs.Config(near=float('nan')))


def test_near_zero_stays_accepted_for_ndc_scenes():
  assert _load("Config.dataset_loader = 'llff'", 'Config.near = 0.', 'Config.far = 1.').near == 0.
  assert _load("Config.generated_rig = 'forward'", 'Config.near = 0.', 'Config.far = 1.').near == 0.
  with pytest.raises(ValueError, match="'dtu' scenes"):
    _load("Config.dataset_loader = 'dtu'", 'Config.near = 0.')


@pytest.mark.parametrize('bindings, message', [
    (['Config.near = 0.5', 'Config.far = 1.'], r"^Config.near = 0.5: 'llff' scenes use NDC rays, which fix near = 0"),
    (['Config.near = 0.', 'Config.far = 6.'], r'^Config.far = 6.0: .*fix near = 0 and far = 1;'),
    (['Config.near = 0.'], r'^Config.far = 6.0: '),
    (['Config.anneal_nearfar = True'], r'^Config.near = 2.0: .*\(Config.anneal_nearfar reads them\)')])
def test_near_far_that_ndc_rays_would_ignore_are_refused(bindings, message):
  with pytest.raises(ValueError, match=message):
    _load("Config.dataset_loader = 'llff'", *bindings)
  with pytest.raises(ValueError, match=message.replace("'llff'", "'generated'")):
    _load("Config.generated_rig = 'forward'", *bindings)
  assert _load("Config.dataset_loader = 'llff'").near == 2.  # Left unset: ignored, as the rays fix them.
  assert _load("Config.dataset_loader = 'llff'", 'Config.near = 0.', 'Config.far = 1.',
               'Config.anneal_nearfar = True').far == 1.


def test_model_background_and_precision_are_bound_through_config_only():
  with pytest.raises(ValueError, match=r'^MipNerfModel.white_background = False: .* bind Config.white_background'):
    _load('MipNerfModel.white_background = False')
  with pytest.raises(ValueError, match=r"^MLP.precision = 'bfloat16': .* bind Config.precision instead"):
    _load("MLP.precision = 'bfloat16'")
  assert not _load('Config.white_background = False').white_background


def test_visible_ratio_without_the_frequency_regularizer_is_refused():
  with pytest.raises(ValueError, match=r'^Config.max_vis_freq_ratio = 0.1 acts only under the frequency regularizer'):
    _load('Config.max_vis_freq_ratio = 0.1', 'Config.freq_reg = False')
  config = _load('Config.max_vis_freq_ratio = 0.1', 'Config.freq_reg = True', 'Config.freq_reg_end = 0')
  point, view = freq_schedule.masks_at(config, (16, 4), 0)
  np.testing.assert_array_equal(point, freq_schedule.fixed_ratio_mask(99, 0.1))
  np.testing.assert_array_equal(view, freq_schedule.fixed_ratio_mask(27, 0.1))


def test_regularizers_that_cannot_act_warn():
  with pytest.warns(UserWarning, match='Config.freq_reg_end = 900 exceeds Config.max_steps = 800'):
    _load('Config.freq_reg = True', 'Config.freq_reg_end = 900', 'Config.max_steps = 800')
  with pytest.warns(UserWarning, match='Config.occ_reg_range = 20 exceeds MipNerfModel.num_samples = 16'):
    _load('Config.occ_reg_loss_mult = 0.01', 'Config.occ_reg_range = 20', 'MipNerfModel.num_samples = 16')


def test_nan_in_llff_bounds_names_the_file(llff_root):
  path = llff_root / 'toy' / 'poses_bounds.npy'
  data = np.load(path)
  data[3, 16] = np.nan
  np.save(path, data)
  with pytest.raises(DatasetError, match=r"poses_bounds\.npy': the near/far bounds of entries \[3\] are not finite"):
    load_dataset('train', llff(llff_root, n_input_views=3))


ZERO_COLUMN = np.array([[0., 1., 0.], [0., 0., 1.], [0., 0., 0.]])  # A rotation whose first column is zero.


@pytest.mark.parametrize('problem, message', [('nan', 'holds NaN or Inf'), ('zero', 'is degenerate: its 3x3 part')])
def test_a_bad_llff_pose_names_the_file_and_its_image(llff_root, problem, message):
  path = llff_root / 'toy' / 'poses_bounds.npy'
  data = np.load(path)
  pose = data[:, :15].reshape(-1, 3, 5)
  pose[4, :, :3] = ZERO_COLUMN if problem == 'zero' else np.nan
  data[:, :15] = pose.reshape(-1, 15)
  np.save(path, data)
  with pytest.raises(DatasetError, match=rf"poses_bounds\.npy': the pose of image 4 \('img04\.png'\) {message}"):
    load_dataset('test', llff(llff_root))  # Test views 0 and 8: image 4 is refused all the same.


@pytest.mark.parametrize('problem, message', [('nan', 'holds NaN or Inf'), ('zero', 'is degenerate: its 3x3 part')])
def test_a_bad_blender_pose_names_the_file_and_its_frame(blender_root, problem, message):
  path = blender_root / 'toy' / 'transforms_train.json'
  meta = json.loads(path.read_text())
  matrix = np.eye(4)
  matrix[:3, :3] = ZERO_COLUMN if problem == 'zero' else np.nan
  meta['frames'][1]['transform_matrix'] = matrix.tolist()
  path.write_text(json.dumps(meta))
  with pytest.raises(DatasetError, match=rf"transforms_train\.json': the transform_matrix of frame 1 "
                                         rf"\('\./train/r_1'\) {message}"):
    load_dataset('train', blender(blender_root))


@pytest.mark.parametrize('problem, message', [('nan', 'holds NaN or Inf'), ('zero', 'is degenerate: its 3x3 part')])
def test_a_bad_dtu_camera_names_the_file_and_the_camera(tmp_path, problem, message):
  projs = synthetic_projections()
  if problem == 'zero':
    projs[7] = 0.  # The world_mat of zeros that numpy called a "Singular matrix".
  else:
    projs[7, 1, 2] = np.inf
  write_idr(tmp_path / 'idr', 'scan24', projs)
  with pytest.raises(DatasetError, match=rf"cameras_sphere\.npz': the projection of camera 7 \(world_mat_7\) "
                                         rf"{message}"):
    load_dataset('train', dtu_config(tmp_path / 'idr', 'scan24'))
  write_regnerf(tmp_path, 'scan24', projs)
  with pytest.raises(DatasetError, match=rf"pos_008\.txt': the projection matrix of camera 7 {message}"):
    load_dataset('train', dtu_config(tmp_path / 'Rectified', 'scan24'))


def test_a_bad_camera_in_a_packed_scene_names_the_pack_and_the_view(tmp_path):
  source = configs.Config(data_dir=str(tmp_path / 'scene'), generated_size=(8, 10), n_input_views=2)
  pack = str(tmp_path / 'scene.npz')
  packed.write_pack(pack, loader.pack_arrays(source, {split: load_dataset(split, source) for split in ('train',
                                                                                                        'test')}))
  with np.load(pack) as f:
    arrays = {k: f[k] for k in f.files}
  arrays['test/camtoworlds'][1, :3, :3] = ZERO_COLUMN
  np.savez(pack, **arrays)
  reloaded = dataclasses.replace(source, dataset_loader='packed', data_dir=pack)
  load_dataset('train', reloaded)
  with pytest.raises(DatasetError, match=r"scene\.npz': the camtoworld of test view 1 \(id \d+\) is degenerate"):
    load_dataset('test', reloaded)


def test_image_of_another_size_names_the_file_and_the_expected_size(llff_root):
  save_png(str(llff_root / 'toy' / 'images_8' / 'img05.png'), noise(5, (7, 8, 3)))
  with pytest.raises(DatasetError, match=r"img05\.png' is 7x8 after loading; expected 6x8 like .*img01\.png"):
    load_dataset('train', llff(llff_root, n_input_views=3))


def test_dtu_mask_path_may_be_a_folder_of_idr_scans(tmp_path):
  write_idr(tmp_path, 'scan24', synthetic_projections())
  own = load_dataset('test', dtu_config(tmp_path, 'scan24'))
  via_path = load_dataset('test', dtu_config(tmp_path, 'scan24', dtu_mask_path=str(tmp_path)))
  np.testing.assert_array_equal(own.masks, via_path.masks)
  assert dtu.mask_folders('m', 'dtu_scan24') == ['m/scan24', 'm/scan24/mask', 'm/dtu_scan24', 'm/dtu_scan24/mask']
  os.remove(tmp_path / 'scan24' / 'mask' / '001.png')
  with pytest.raises(DatasetError, match=r"not all present in any of \[.*scan24', .*scan24/mask'\]"):
    load_dataset('test', dtu_config(tmp_path, 'scan24', dtu_mask_path=str(tmp_path)))


def test_zero_render_path_frames_is_refused_naming_the_setting():
  with pytest.raises(ValueError, match=r'Config\.render_path_frames = 0; expected a positive integer'):
    tiny_config('s', 'run', 'Config.render_path_frames = 0')
