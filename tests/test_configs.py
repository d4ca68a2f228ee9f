"""Every .gin file parses; ours hold the released values; the 20 released files parse and train as they are."""

import dataclasses
import pathlib

import numpy as np
import pytest

from conftest import SHARED_DATA
from internal import runs
from internal.models import freq_schedule
from internal import config_loader
from internal import configs
from internal import datasets
from internal.models import mip_nerf
from internal.models import nerf
from internal.pipeline import loop
from internal.training import schedule
from internal import cli

ROOT = pathlib.Path(__file__).resolve().parents[1]
COMMON = ROOT / 'configs' / 'common'  # Blocks shared by `include`, not configs of their own.
CONFIG_FILES = sorted(p for p in (ROOT / 'configs').rglob('*.gin') if p.parent != COMMON)
LR_BLOCK = {'lr_init': 0.002, 'lr_final': 0.00002, 'lr_delay_steps': 512, 'lr_delay_mult': 0.01,
            'grad_max_norm': 0.1, 'grad_max_val': 0.1}
# The released configs' (max_steps, freq_reg_end) per setting, written out here independently of the config files.
STEPS = {('dtu', 3): (43945, 39550), ('dtu', 6): (87891, 61524), ('dtu', 9): (131836, 65918),
         ('llff', 3): (69768, 62791), ('llff', 6): (139535, 97675), ('llff', 9): (209303, 104651)}


RELEASED_DIR = SHARED_DATA / 'released_configs'
RELEASED = [f'{m}/{d}{n}_{m}.gin' for m in ('freenerf', 'mipnerf', 'regnerf') for d in ('dtu', 'llff') for n in (3, 6, 9)]
RELEASED += ['mipnerf/dtu_mipnerf_all.gin', 'mipnerf/llff_mipnerf_all.gin']
SCENES = {'dtu': (SHARED_DATA / 'dtu', "Config.dtu_scan = 'dtu_scan24'"),
          'llff': (SHARED_DATA / 'llff', "Config.llff_scan = 'fern'")}


def _released(name: str) -> str:
  """Path of a released FreeNeRF-repo .gin file, byte for byte; skips, saying why, when it is absent."""
  path = RELEASED_DIR / name
  if not path.is_file():
    pytest.skip(f'the released config {name} is not under {RELEASED_DIR}')
  return str(path)


def _write(tmp_path, text: str) -> str:
  """Writes a .gin file and returns its path."""
  path = tmp_path / 'released.gin'
  path.write_text(text)
  return str(path)


def _run_bindings(name: str, run) -> list:
  """The data and run bindings a user adds to a released file: data_dir, scene, checkpoint_dir, steps, batch.

  Config.batch_size_random (random-pose rays of the RegNeRF files) is a run size too: one 8x8 patch keeps
  the paper-size model's step short on a CPU. The shared DTU scan is in the IDR layout with its masks beside
  the images and 13 of the 25 test views, which the DTU data bindings say (train.py checks the test split
  before training).
  """
  dataset = 'dtu' if '/dtu' in name else 'llff'
  data_dir, scene = SCENES[dataset]
  if not data_dir.is_dir():
    pytest.skip(f'no shared scene under {data_dir}')
  layout = [f"Config.dtu_mask_path = '{data_dir}'", 'Config.allow_missing_test_views = True']
  return [f"Config.data_dir = '{data_dir}'", scene, *(layout if dataset == 'dtu' else []),
          f"Config.checkpoint_dir = '{run}'", 'Config.max_steps = 2', 'Config.batch_size = 64',
          'Config.batch_size_random = 64']


@pytest.mark.parametrize('name', RELEASED)
def test_released_gin_files_parse_unchanged(name):
  config = config_loader.load_config([_released(name)], ["Config.data_dir = 'elsewhere'"])
  mip_nerf.MipNerfModel(), mip_nerf.MLP()  # Applies (and so checks) every model binding.
  assert config.data_dir == 'elsewhere' and mip_nerf.MLP().density_noise == 1.0
  assert config.freq_reg == name.startswith('freenerf')
  assert mip_nerf.MipNerfModel().ray_shape == ('cylinder' if '/llff' in name else 'cone')
  assert config.load_random_rays == name.startswith('regnerf')  # Unset (released default True) in RegNeRF's.
  assert (config.depth_tvnorm_loss_mult, config.depth_tvnorm_decay) == (
      (0.1, True) if name.startswith('regnerf') else (0., False))


# The one released file that needs an image the shared DTU scan lacks (it holds 22 of scan24's 49 images): every
# training view, the first missing of which is this one. Any other missing image is a view-selection error.
ALL_VIEWS_GAP = ('mipnerf/dtu_mipnerf_all.gin', 'dtu_scan24/images/000002.png')


@pytest.mark.parametrize('name', RELEASED)
def test_released_gin_files_train_two_steps_on_the_shared_scenes(tmp_path, name):
  config = config_loader.load_config([_released(name)], _run_bindings(name, tmp_path / 'run'))
  try:
    result = loop.train(config)
  except datasets.DatasetNotFoundError as err:
    gap = str(SCENES['dtu'][0] / ALL_VIEWS_GAP[1])
    if name != ALL_VIEWS_GAP[0] or str(err) != f'DTU training image: file {gap!r} does not exist':
      raise
    pytest.skip(f'the shared scene lacks training views that {name} uses: {err}')
  assert int(result.state.step) == 2 and result.signum is None
  assert (tmp_path / 'run' / 'checkpoints' / '2').is_dir()


def test_released_llff9_regnerf_warmup_end_is_the_old_name_of_freq_reg_end(tmp_path):
  config = config_loader.load_config([_released('regnerf/llff9_regnerf.gin')])
  assert (config.warmup_end, config.freq_reg_end, config.freq_reg) == (0, 0, False)
  path = _write(tmp_path, 'Config.freq_reg = True\nConfig.warmup_end = 500')
  assert runs.bind_fresh([path]).freq_reg_end == 500
  with pytest.raises(ValueError, match='warmup_end'):
    runs.bind_fresh([path], ['Config.freq_reg_end = 400'])


def test_released_all_views_value_selects_every_training_view(capsys):
  assert datasets.base.first_n([3, 5, 8], 100, 'pool') == [3, 5, 8]
  assert 'every view' in capsys.readouterr().out
  with pytest.raises(datasets.DatasetError, match='n_input_views = 7'):
    datasets.base.first_n([3, 5, 8], 7, 'pool')


def test_unknown_binding_is_an_error_naming_it(tmp_path):
  path = _write(tmp_path, 'Config.max_steps = 3\nConfig.warmup_start = 0\n')
  with pytest.raises(ValueError, match='warmup_start'):
    config_loader.load_config([path])


def test_flow_loss_is_a_clear_error():
  with pytest.raises(ValueError, match='flow_loss_mult.*never released'):
    config_loader.load_config([], ['Config.flow_loss_mult = 0.1'])


@pytest.mark.parametrize('path', CONFIG_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_config_file_parses_and_validates(path):
  config = runs.bind_fresh([str(path)])
  mip_nerf.MipNerfModel(), mip_nerf.MLP(), nerf.NerfModel(), nerf.NerfMLP()  # Applies (checks) every model binding.
  assert config.checkpoint_dir.startswith('out/')


def _ours(method: str, dataset: str, n: int):
  """Our config of a paper setting."""
  return config_loader.load_config([str(ROOT / 'configs' / method / f'{dataset}{n}_{method}.gin')])


@pytest.mark.parametrize('dataset,n', sorted(STEPS))
def test_freenerf_configs_hold_the_released_values(dataset, n):
  config = _ours('freenerf', dataset, n)
  assert (config.max_steps, config.freq_reg_end) == STEPS[dataset, n]
  assert config.freq_reg and config.freq_mask_layout == 'released' and config.downsample_mode == 'released'
  assert {k: getattr(config, k) for k in LR_BLOCK} == LR_BLOCK
  assert config.occ_reg_loss_mult == 0.01 and config.n_input_views == n
  assert (config.occ_reg_range, config.occ_wb_prior) == ((10, True) if dataset == 'dtu' else (20, False))
  assert (config.near, config.far, config.factor) == ((0.5, 3.5, 4) if dataset == 'dtu' else (0., 1., 8))
  assert not config.white_background and mip_nerf.MLP().density_noise == 1.0
  assert mip_nerf.MipNerfModel().ray_shape == ('cone' if dataset == 'dtu' else 'cylinder')


@pytest.mark.parametrize('dataset,n', sorted(STEPS))
def test_mipnerf_configs_are_freenerf_without_regularizers(dataset, n):
  config = _ours('mipnerf', dataset, n)
  assert config.max_steps == STEPS[dataset, n][0] and config.n_input_views == n
  assert freq_schedule.masks_at(config, mip_nerf.MLP().encoding_degrees(), 0) == (None, None) and config.occ_reg_loss_mult == 0.
  assert {k: getattr(config, k) for k in LR_BLOCK} == LR_BLOCK


@pytest.mark.parametrize('dataset', ['dtu', 'llff'])
def test_mipnerf_all_configs_use_the_default_schedule(dataset):
  config = config_loader.load_config([str(ROOT / 'configs' / 'mipnerf' / f'{dataset}_mipnerf_all.gin')])
  default = configs.Config()
  assert config.max_steps == 500000 and config.n_input_views == 0  # Every training view.
  assert (config.lr_init, config.lr_final, config.lr_delay_steps, config.grad_max_norm) == (
      default.lr_init, default.lr_final, 0, 0.)


BLENDER_NERF = ['nerf/blender8_nerf.gin', 'nerf/blender8_nerf_200k.gin', 'freenerf/blender8_freenerf.gin',
                'freenerf/blender8_freenerf_200k.gin']


@pytest.mark.parametrize('name', BLENDER_NERF + ['mipnerf/blender8_mipnerf_freenerf.gin'])
def test_blender_configs_follow_the_dietnerf_data_protocol(name):
  config = config_loader.load_config([str(ROOT / 'configs' / name)])
  assert (config.dataset_loader, config.blender_split, config.n_input_views) == ('blender', 'dietnerf', 8)
  assert (config.factor, config.downsample_mode, config.white_background) == (2, 'area', True)
  assert (config.near, config.far) == (2., 6.)
  mipnerf = name.startswith('mipnerf')
  # NeRF: the Blender code's integer pixel coordinates; our mip-NeRF stand-in keeps its pixel-centre cones.
  assert config.pixel_offset == (.5 if mipnerf else 0.)
  if config.freq_reg:
    assert config.freq_reg_end == config.max_steps // 2
    assert config.freq_mask_layout == ('paper' if mipnerf else 'released')
    assert config.occ_reg_range == 20 and not config.occ_wb_prior


@pytest.mark.parametrize('name', BLENDER_NERF)
def test_blender_nerf_configs_follow_the_blender_code_recipe(name):
  config = config_loader.load_config([str(ROOT / 'configs' / name)])
  mlp, model = nerf.NerfMLP(), nerf.NerfModel()
  assert config.model == 'nerf' and model.fine_samples_per_ray() == 192
  assert (mlp.net_depth, mlp.net_width, mlp.net_width_viewdirs, mlp.skip_layer) == (8, 256, 128, 4)
  assert (mlp.deg_point, mlp.deg_view, model.num_coarse_samples, model.num_fine_samples) == (10, 4, 64, 128)
  assert (config.batching, config.batch_size, config.precrop_steps, config.precrop_frac) == (
      'single_image', 1024, 500, 0.5)
  assert config.max_steps == (200000 if '200k' in name else 50000) and config.coarse_loss_mult == 1.
  # lr(t) = 5e-4 * 0.1^(t / 500k), written out independently of the schedule code.
  for step in (0, 1234, config.max_steps):
    lr = schedule.config_learning_rate(config, step)
    np.testing.assert_allclose(lr, 5e-4 * 0.1**(step / 500000), rtol=1e-5)
  assert (config.grad_max_val, config.grad_max_norm, config.lr_delay_steps) == (0., 0., 0)
  # 0.01 against the Blender code's per-channel MSE = 0.03 against our 3x-MSE data loss.
  assert config.occ_reg_loss_mult == (0.03 if name.startswith('freenerf') else 0.)


def test_freenerf_mask_of_the_dtu3_config_opens_as_released():
  config = _ours('freenerf', 'dtu', 3)
  point, view = freq_schedule.masks_at(config, mip_nerf.MLP().encoding_degrees(), config.freq_reg_end // 2)
  point = np.asarray(point)
  assert point.shape == (99,) and np.asarray(view).shape == (27,)
  assert np.all(point[:51] == 1.) and np.all(point[54:] < 1e-6)  # t/T = 0.5: every sin band, no cos.


def test_flags_repeat_and_take_several_values(tmp_path):
  first, second = _write(tmp_path, 'Config.max_steps = 7'), str(tmp_path / 'second.gin')
  pathlib.Path(second).write_text('Config.batch_size = 64')
  args = cli.flag_parser('test').parse_args(
      ['--gin_configs', first, f'--gin_configs={second}', '--gin_bindings', 'Config.print_every = 3',
       'Config.n_input_views = 6', '--gin_bindings=Config.max_steps = 9'])
  assert args.gin_configs == [first, second]
  config = cli.config_from_flags(args)
  assert (config.max_steps, config.batch_size, config.print_every, config.n_input_views) == (9, 64, 3, 6)


# Where our configs, includes expanded, deliberately differ from the released file of the same name; every other
# value (Config defaults included) must be equal. Naming: the released files write 'myexp' / 'out/myexp' and
# copy one project name ('dtu3_bkgd', 'llff3') into several files.
NAMING = {'Config.expname', 'Config.project', 'Config.checkpoint_dir'}
DIFFERENCES = {
    # Released False; random-pose patches are only made for depth smoothness, which these configs leave off.
    'freenerf/': {'Config.load_random_rays'},
    'mipnerf/': {'Config.load_random_rays'},
    # Released 100 means every training view, which our loader spells 0.
    '_mipnerf_all': {'Config.n_input_views'},
    # The two released RegNeRF bugs corrected (docs/regnerf.md).
    'regnerf/': {'Config.regnerf_fix_released_bugs'},
    # Our RegNeRF LLFF configs default to the fern scene (released: horns); runs set the scene anyway.
    'regnerf/llff': {'Config.llff_scan'},
    # Released values of settings that anneal_nearfar = False leaves unused; ours keep the defaults.
    'regnerf/dtu9': {'Config.anneal_nearfar_steps', 'Config.anneal_nearfar_perc'},
    # Bookkeeping (not fingerprinted): which test views a learning curve scores, if one is asked for.
    '/dtu': {'Config.curve_spread_views'},
}


def _effective(path) -> dict:
  """Every value a .gin file leaves in effect: the Config fields and the MLP and MipNerfModel settings.

  The model's own MLP (MipNerfModel.mlp) is compared through the MLP.* settings.
  """
  values = {f'Config.{k}': v for k, v in dataclasses.asdict(runs.bind_fresh([str(path)])).items()}
  for module in (mip_nerf.MLP(), mip_nerf.MipNerfModel()):
    values.update({f'{type(module).__name__}.{f.name}': getattr(module, f.name)
                   for f in dataclasses.fields(module) if f.name not in ('parent', 'name', 'mlp')})
  return values


@pytest.mark.parametrize('name', RELEASED)
def test_expanded_config_equals_the_released_file_but_for_documented_differences(name):
  released, ours = _effective(_released(name)), _effective(ROOT / 'configs' / name)
  assert set(released) == set(ours)
  differing = {k for k in ours if ours[k] != released[k]}
  documented = set().union(*[v for key, v in DIFFERENCES.items() if key in name])
  assert differing - NAMING == documented, {k: (released[k], ours[k]) for k in differing ^ documented}


def test_every_common_block_is_included_and_resolves_from_another_directory(tmp_path, monkeypatch):
  texts = '\n'.join(p.read_text() for p in (ROOT / 'configs').rglob('*.gin'))
  studies = '\n'.join(p.read_text() for p in (ROOT / 'studies').glob('*.toml'))
  for block in COMMON.glob('*.gin'):  # Included by a config, or a study's block for its methods' configs lists.
    assert (f"include 'configs/common/{block.name}'" in texts
            or f'"configs/common/{block.name}"' in studies), block.name
  expected = _effective(ROOT / 'configs' / 'regnerf' / 'llff3_regnerf.gin')
  monkeypatch.chdir(tmp_path)  # gin resolves includes against its search path, not only the working directory.
  assert _effective(ROOT / 'configs' / 'regnerf' / 'llff3_regnerf.gin') == expected
  assert expected['Config.depth_tvnorm_loss_mult'] == 0.1 and expected['MipNerfModel.ray_shape'] == 'cylinder'
