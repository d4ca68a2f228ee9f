"""Every .gin file parses; ours hold the released values; the released FreeNeRF / mip-NeRF files parse as is."""

import pathlib

import gin
import numpy as np
import pytest
from jax import random

from conftest import SHARED_DATA
from internal import configs
from internal import datasets
from internal import models
from internal import run_dir
from internal import train_step

ROOT = pathlib.Path(__file__).resolve().parents[1]
CONFIG_FILES = sorted((ROOT / 'configs').rglob('*.gin'))
LR_BLOCK = {'lr_init': 0.002, 'lr_final': 0.00002, 'lr_delay_steps': 512, 'lr_delay_mult': 0.01,
            'grad_max_norm': 0.1, 'grad_max_val': 0.1}
# PROTOCOL §4/§6: (max_steps, freq_reg_end) per setting, written out here independently of the config files.
STEPS = {('dtu', 3): (43945, 39550), ('dtu', 6): (87891, 61524), ('dtu', 9): (131836, 65918),
         ('llff', 3): (69768, 62791), ('llff', 6): (139535, 97675), ('llff', 9): (209303, 104651)}


def _released(dataset: str, n: int, method: str) -> str:
  """The bindings of a released FreeNeRF-repo .gin file (PROTOCOL §6), as the released files spell them."""
  steps, end = STEPS[dataset, n] if n < 100 else (500000, 0)
  lines = ["Config.expname = 'myexp'", "Config.checkpoint_dir = 'out/myexp'", f"Config.project = '{dataset}{n}'",
           "Config.dtu_scan = 'scan8'", "Config.data_dir = 'data/Rectified/images'",
           "Config.dtu_mask_path = 'data/Rectified/mask'", f"Config.dataset_loader = '{dataset}'",
           'Config.white_background = False', 'MLP.density_noise = 1.0', f'Config.n_input_views = {n}',
           f'Config.max_steps = {steps}']
  lines += (['Config.near = 0.5', 'Config.far = 3.5', 'Config.factor = 4', 'Config.render_factor = 4']
            if dataset == 'dtu' else
            ["Config.llff_scan = 'horns'", "MipNerfModel.ray_shape = 'cylinder'", 'Config.near = 0.',
             'Config.far = 1.', 'Config.factor = 8', 'Config.render_factor = 8'])
  if n < 100:
    lines += [f'Config.{k} = {v}' for k, v in LR_BLOCK.items()]
  else:
    lines += ["Config.dtu_split_type = 'depth_eval'"]
  if method == 'freenerf':
    lines += ['Config.freq_reg = True', f'Config.freq_reg_end = {end}', 'Config.occ_reg_loss_mult = 0.01',
              f'Config.occ_wb_prior = {dataset == "dtu"}']
    lines += ['Config.occ_reg_range = 20'] if dataset == 'llff' else []
  else:
    lines += ['Config.freq_reg = False', 'Config.freq_reg_end = 0', 'Config.occ_reg_loss_mult = 0.']
  return '\n'.join(lines)


RELEASED = [(d, n, m) for d in ('dtu', 'llff') for n in (3, 6, 9) for m in ('freenerf', 'mipnerf')]
RELEASED += [('dtu', 100, 'mipnerf'), ('llff', 100, 'mipnerf')]


def _write(tmp_path, text: str) -> str:
  """Writes a .gin file and returns its path."""
  path = tmp_path / 'released.gin'
  path.write_text(text)
  return str(path)


@pytest.mark.parametrize('dataset,n,method', RELEASED)
def test_released_gin_files_parse_with_only_data_dir_changed(tmp_path, dataset, n, method):
  path = _write(tmp_path, _released(dataset, n, method))
  config = configs.load_config([path], [f"Config.data_dir = '{tmp_path}'"])
  assert config.data_dir == str(tmp_path) and config.n_input_views == n
  assert config.freq_reg == (method == 'freenerf')
  assert models.MipNerfModel().ray_shape == ('cylinder' if dataset == 'llff' else 'cone')
  assert models.MLP().density_noise == 1.0


def test_unknown_binding_is_an_error_naming_it(tmp_path):
  path = _write(tmp_path, _released('llff', 9, 'mipnerf') + '\nConfig.warmup_end = 0\n')
  with pytest.raises(ValueError, match='warmup_end'):
    configs.load_config([path])


@pytest.mark.parametrize('path', CONFIG_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_config_file_parses_and_validates(path):
  gin.clear_config()
  config = configs.load_config([str(path)])
  models.MipNerfModel(), models.MLP()  # Applies (and so checks) every model binding.
  assert config.checkpoint_dir.startswith('out/')


def _ours(method: str, dataset: str, n: int):
  """Our config of a paper setting."""
  return configs.load_config([str(ROOT / 'configs' / method / f'{dataset}{n}_{method}.gin')])


@pytest.mark.parametrize('dataset,n', sorted(STEPS))
def test_freenerf_configs_hold_the_released_values(dataset, n):
  config = _ours('freenerf', dataset, n)
  assert (config.max_steps, config.freq_reg_end) == STEPS[dataset, n]
  assert config.freq_reg and config.freq_mask_layout == 'released' and config.downsample_mode == 'released'
  assert {k: getattr(config, k) for k in LR_BLOCK} == LR_BLOCK
  assert config.occ_reg_loss_mult == 0.01 and config.n_input_views == n
  assert (config.occ_reg_range, config.occ_wb_prior) == ((10, True) if dataset == 'dtu' else (20, False))
  assert (config.near, config.far, config.factor) == ((0.5, 3.5, 4) if dataset == 'dtu' else (0., 1., 8))
  assert not config.white_background and models.MLP().density_noise == 1.0
  assert models.MipNerfModel().ray_shape == ('cone' if dataset == 'dtu' else 'cylinder')


@pytest.mark.parametrize('dataset,n', sorted(STEPS))
def test_mipnerf_configs_are_freenerf_without_regularizers(dataset, n):
  config = _ours('mipnerf', dataset, n)
  assert config.max_steps == STEPS[dataset, n][0] and config.n_input_views == n
  assert train_step.masks_at(config, 0) == (None, None) and config.occ_reg_loss_mult == 0.
  assert {k: getattr(config, k) for k in LR_BLOCK} == LR_BLOCK


@pytest.mark.parametrize('dataset', ['dtu', 'llff'])
def test_mipnerf_all_configs_use_the_default_schedule(dataset):
  config = configs.load_config([str(ROOT / 'configs' / 'mipnerf' / f'{dataset}_mipnerf_all.gin')])
  default = configs.Config()
  assert config.max_steps == 500000 and config.n_input_views == 0  # Every training view.
  assert (config.lr_init, config.lr_final, config.lr_delay_steps, config.grad_max_norm) == (
      default.lr_init, default.lr_final, 0, 0.)


def test_blender_config_follows_the_dietnerf_protocol():
  config = configs.load_config([str(ROOT / 'configs' / 'freenerf' / 'blender8_freenerf.gin')])
  assert (config.dataset_loader, config.blender_split, config.n_input_views) == ('blender', 'dietnerf', 8)
  assert (config.factor, config.downsample_mode, config.white_background) == (2, 'area', True)
  assert (config.near, config.far, config.freq_mask_layout) == (2., 6., 'paper')
  assert config.freq_reg_end == config.max_steps // 2


def test_freenerf_mask_of_the_dtu3_config_opens_as_released():
  config = _ours('freenerf', 'dtu', 3)
  point, view = train_step.masks_at(config, config.freq_reg_end // 2)
  point = np.asarray(point)
  assert point.shape == (99,) and np.asarray(view).shape == (27,)
  assert np.all(point[:51] == 1.) and np.all(point[54:] < 1e-6)  # t/T = 0.5: every sin band, no cos.


def test_released_llff_config_trains_a_step_on_real_data(tmp_path):
  if not (SHARED_DATA / 'llff' / 'fern').is_dir():
    pytest.skip(f'no LLFF fern scene under {SHARED_DATA}')
  path = _write(tmp_path, _released('llff', 3, 'freenerf'))
  config = configs.load_config([path], [f"Config.data_dir = '{SHARED_DATA / 'llff'}'",
                                        "Config.llff_scan = 'fern'", 'Config.batch_size = 32'])
  batcher = datasets.make_batcher(datasets.load_dataset('train', config), config)
  batch = batcher(1)
  model, state = train_step.create_train_state(config, random.PRNGKey(0), batch['rays'])
  state, stats = train_step.make_train_step(config, model)(state, batch, random.PRNGKey(1))
  assert int(state.step) == 1 and np.isfinite(float(stats['loss'])) and bool(stats['grads_finite'])


def test_flags_repeat_and_take_several_values(tmp_path):
  first, second = _write(tmp_path, 'Config.max_steps = 7'), str(tmp_path / 'second.gin')
  pathlib.Path(second).write_text('Config.batch_size = 64')
  args = run_dir.flag_parser('test').parse_args(
      ['--gin_configs', first, f'--gin_configs={second}', '--gin_bindings', 'Config.print_every = 3',
       'Config.n_input_views = 6', '--gin_bindings=Config.max_steps = 9'])
  assert args.gin_configs == [first, second]
  config = run_dir.config_from_flags(args)
  assert (config.max_steps, config.batch_size, config.print_every, config.n_input_views) == (9, 64, 3, 6)
