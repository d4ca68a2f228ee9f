"""Every Config field says what it does (a comment on its line or on the line above) and declares its properties,
which the code that acts on them follows: ranges, the fingerprint, packs, paths, the model's fields, seeds."""

import dataclasses
import math
import pathlib
import re

import pytest

from internal import config_loader
from internal import configs
from internal.configs import Config
from internal.datasets import loader
from internal.datasets import packed
from internal.run import run_dir

SOURCE = pathlib.Path(__file__).resolve().parents[1] / 'internal' / 'configs.py'


def uncommented_fields(lines) -> list:
  """Names of `  name: type = value` lines with no `#` comment on them or on the line before."""
  missing = []
  for i, line in enumerate(lines):
    match = re.match(r'  (\w+): [^=]+=', line)
    if match and '#' not in line and not lines[i - 1].strip().startswith('#'):
      missing.append(match.group(1))
  return missing


def test_uncommented_fields_finds_a_bare_field():
  assert uncommented_fields(['  # Data.', '  a: int = 1  # A.', '  b: int = 2', '  # C.', '  c: int = 3']) == ['b']


def test_every_config_field_is_commented():
  lines = SOURCE.read_text().splitlines()
  declared = [m.group(1) for m in (re.match(r'  (\w+): [^=]+=', line) for line in lines) if m]
  assert declared == [f.name for f in dataclasses.fields(Config)]  # The parser sees every field.
  assert uncommented_fields(lines) == []


# ------------------------------------------------------------------ the properties each field declares

FIELDS = dataclasses.fields(Config)


def test_every_field_declares_its_properties_with_setting():
  for field in FIELDS:  # A bare `name: int = 3` has no metadata: it must say what it is.
    assert set(field.metadata) == {'properties', 'shapes', 'hint', 'at_most'}, field.name
    assert field.metadata['properties'] <= set(configs.PROPERTIES), field.name
    assert set(field.metadata['shapes']) <= set(loader.LOADERS) | {configs.ALL_LOADERS}, field.name
  with pytest.raises(ValueError, match=r"unknown setting properties \['postive'\]"):
    configs.setting(1, 'postive')


F, P, NN = configs.FINITE, configs.POSITIVE, configs.NON_NEGATIVE
# Every Config field with a range and the ranges it must have, written out here rather than read from the
# declarations, so that a range dropped from (or added to) a declaration fails. Every float is finite (in float32).
EXPECTED_RANGES = {
    'checkpoint_every': {P}, 'checkpoint_keep': {P}, 'print_every': {P}, 'render_chunk_size': {P},
    'factor': {NN}, 'render_factor': {NN}, 'n_input_views': {NN}, 'batch_size': {P}, 'near': {F}, 'far': {F},
    'near_origin': {F}, 'pixel_offset': {F}, 'render_path_frames': {P}, 'precrop_steps': {NN},
    'precrop_frac': {F}, 'max_steps': {P}, 'lr_init': {F, P}, 'lr_final': {F, P}, 'lr_delay_steps': {NN},
    'lr_delay_mult': {F}, 'grad_max_norm': {F}, 'grad_max_val': {F}, 'adam_eps': {F}, 'max_skipped_steps': {P},
    'coarse_loss_mult': {F}, 'weight_decay_mult': {F}, 'resample_padding_init': {F},
    'resample_padding_final': {F}, 'stuck_warning_steps': {NN}, 'freq_reg_end': {NN}, 'max_vis_freq_ratio': {F},
    'occ_reg_loss_mult': {F}, 'occ_reg_range': {NN}, 'occ_wb_range': {NN}, 'distortion_loss_mult': {F},
    'n_random_poses': {P}, 'random_pose_radius': {F}, 'depth_tvnorm_loss_mult': {F},
    'depth_tvnorm_loss_mult_start': {F}, 'depth_tvnorm_loss_mult_end': {F}, 'depth_tvnorm_mask_weight': {F},
    'anneal_nearfar_steps': {P}, 'anneal_nearfar_perc': {F}, 'anneal_mid_perc': {F}, 'flow_loss_mult': {F},
    'eval_factor': {P}, 'curve_every': {NN}, 'curve_spread_views': {NN}, 'curve_factor': {P},
    'depth_rank_loss_mult': {F, NN}, 'depth_rank_margin': {F, NN}, 'depth_pearson_loss_mult': {F, NN},
    'depth_patch_size': {P}, 'depth_prior_rays': {P}, 'sfm_depth_loss_mult': {F, NN},
    'camera_lr_init': {F, P}, 'camera_lr_final': {F, P}, 'camera_lr_delay_steps': {NN}, 'camera_lr_delay_mult': {F},
    'camera_adam_eps': {F, P}, 'coarse_to_fine_start': {F, NN}, 'coarse_to_fine_end': {F, P},
    'camera_noise_rotation_deg': {F, NN}, 'camera_noise_translation': {F, NN},
    'test_pose_steps': {NN}, 'test_pose_lr': {F, P}}
EXPECTED_AT_MOST = {'camera_noise_rotation_deg': 180.}


def test_each_field_declares_exactly_the_ranges_the_table_expects():
  declared = {f.name: set(f.metadata['properties']) & set(configs.RANGES) for f in FIELDS}
  assert {name: ranges for name, ranges in declared.items() if ranges} == EXPECTED_RANGES


def test_every_float_setting_is_finite_in_float32():
  assert {f.name for f in FIELDS if isinstance(f.default, float)} <= set(configs.declared(F))
  assert {f.name: f.metadata['at_most'] for f in FIELDS if f.metadata['at_most'] is not None} == EXPECTED_AT_MOST


def _out_of_range(kind: str, default):
  return {F: math.inf, NN: -1}.get(kind, 0. if isinstance(default, float) else 0)


@pytest.mark.parametrize('name, kind', [(n, k) for n, kinds in EXPECTED_RANGES.items() for k in sorted(kinds)])
def test_a_value_outside_each_fields_range_is_refused_naming_it(name, kind):
  field = next(f for f in FIELDS if f.name == name)
  value = _out_of_range(kind, field.default)
  why = {F: 'a finite number', NN: '>= 0'}.get(kind, '> 0' if isinstance(field.default, float) else
                                                 'a positive integer')
  hint = f' ({field.metadata["hint"]})' if field.metadata['hint'] else ''
  with pytest.raises(ValueError, match='^' + re.escape(f'Config.{name} = {value}; expected {why}{hint}') + '$'):
    config_loader.validate(dataclasses.replace(Config(), **{name: value}))


def _other_value(field):
  """A value of the field's type other than its default."""
  value = field.default
  if field.name == 'model':
    return 'nerf'
  if isinstance(value, bool):
    return not value
  if isinstance(value, (int, float)):
    return value + 1
  return value + 'x' if isinstance(value, str) else (7, 8)


def test_exactly_the_bookkeeping_fields_leave_the_fingerprint_unchanged():
  base = run_dir.fingerprint(Config())
  for field in FIELDS:
    changed = run_dir.fingerprint(dataclasses.replace(Config(), **{field.name: _other_value(field)})) != base
    assert changed == (configs.BOOKKEEPING not in field.metadata['properties']), field.name
  bookkeeping = set(configs.declared(configs.BOOKKEEPING))
  assert {'checkpoint_dir', 'data_dir', 'print_every', 'compute_lpips', 'test_view_ids'} <= bookkeeping
  assert not {'max_steps', 'lr_init', 'freq_reg', 'n_input_views', 'train_view_ids', 'jax_rng_seed'} & bookkeeping


def test_a_pack_records_the_settings_that_shape_its_loaders_data():
  for name in loader.LOADERS:
    recorded = packed.settings(Config(dataset_loader=name))
    shaping = {f.name for f in FIELDS if {name, configs.ALL_LOADERS} & set(f.metadata['shapes'])}
    assert set(recorded) == shaping, name
  assert {'train_view_ids', 'test_view_ids', 'factor'} <= set(configs.shaping_settings(configs.ALL_LOADERS))


def test_exactly_the_path_fields_expand_a_home_folder(monkeypatch):
  monkeypatch.setenv('HOME', '/home/someone')
  text = [f for f in FIELDS if isinstance(f.default, str)]
  expanded = config_loader._expand_home(Config(**{f.name: '~/x' for f in text}))
  assert {f.name for f in text if getattr(expanded, f.name) == '/home/someone/x'} == set(configs.declared(
      configs.PATH))


@pytest.mark.parametrize('name', configs.declared(configs.TO_MODEL))
def test_the_fields_set_into_the_model_are_refused_as_its_gin_bindings(name):
  with pytest.raises(ValueError, match=f'bind Config.{name} instead'):
    config_loader.parse_gin([], [f'MipNerfModel.{name} = None'])


def test_the_seeds_are_those_metrics_json_records():
  assert configs.declared(configs.SEED) == ('jax_rng_seed', 'np_rng_seed')  # Its "seeds": [jax, np].


@pytest.mark.parametrize('value', [-1, 2**63, 1180591620717411303424])
@pytest.mark.parametrize('name', configs.declared(configs.RNG_SEED))
def test_a_seed_no_random_generator_takes_is_refused_naming_it(name, value):
  with pytest.raises(ValueError, match=re.escape(f'Config.{name} = {value}; expected a whole number in [0, 2^63)')):
    config_loader.validate(dataclasses.replace(Config(), **{name: value}))
  config_loader.validate(dataclasses.replace(Config(), **{name: 2**63 - 1}))


def _expected_line(name: str, value, why: str) -> str:
  """The whole error line of Config.<name> = value, its hint included, as a regular expression."""
  hint = next(f.metadata['hint'] for f in FIELDS if f.name == name)
  return '^' + re.escape(f'Config.{name} = {value}; expected {why}' + (f' ({hint})' if hint else '')) + '$'


@pytest.mark.parametrize('name', configs.declared(F))
@pytest.mark.parametrize('value', [1e39, -1e39, 10**39])
def test_a_finite_setting_beyond_float32_is_refused_naming_it(name, value):
  with pytest.raises(ValueError, match=_expected_line(name, value, 'a finite number float32 holds (|x| <= 3.403e+38)')):
    config_loader.validate(dataclasses.replace(Config(), **{name: value}))


@pytest.mark.parametrize('name', [f.name for f in FIELDS if P in f.metadata['properties'] and
                                  isinstance(f.default, float)])
def test_a_positive_float_that_float32_flushes_to_zero_is_refused_naming_it(name):
  with pytest.raises(ValueError, match=_expected_line(name, 1e-40, 'a positive number float32 holds (>= 1.175e-38)')):
    config_loader.validate(dataclasses.replace(Config(), **{name: 1e-40}))
  config_loader.validate(dataclasses.replace(Config(), **{name: 2e-38}))


@pytest.mark.parametrize('name, bound', EXPECTED_AT_MOST.items())
def test_a_value_above_a_fields_at_most_is_refused_naming_it(name, bound):
  with pytest.raises(ValueError, match=_expected_line(name, 1e9, f'<= {bound:g}')):
    config_loader.validate(dataclasses.replace(Config(), **{name: 1e9}))
  config_loader.validate(dataclasses.replace(Config(), **{name: bound}))


def test_the_seeds_of_every_random_generator_are_checked():
  assert configs.declared(configs.RNG_SEED) == ('jax_rng_seed', 'np_rng_seed', 'generated_seed', 'camera_noise_seed')
  assert set(configs.declared(configs.SEED)) <= set(configs.declared(configs.RNG_SEED))
