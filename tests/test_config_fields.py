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
    assert set(field.metadata) == {'properties', 'shapes', 'hint'}, field.name
    assert field.metadata['properties'] <= set(configs.PROPERTIES), field.name
    assert set(field.metadata['shapes']) <= set(loader.LOADERS) | {configs.ALL_LOADERS}, field.name
  with pytest.raises(ValueError, match=r"unknown setting properties \['postive'\]"):
    configs.setting(1, 'postive')


F, P, NN = configs.FINITE, configs.POSITIVE, configs.NON_NEGATIVE
# Every Config field with a range and the ranges it must have, written out here rather than read from the
# declarations, so that a range dropped from (or added to) a declaration fails.
EXPECTED_RANGES = {
    'checkpoint_every': {P}, 'checkpoint_keep': {P}, 'print_every': {P}, 'render_chunk_size': {P},
    'factor': {NN}, 'render_factor': {NN}, 'n_input_views': {NN}, 'batch_size': {P}, 'near': {F}, 'far': {F},
    'render_path_frames': {P}, 'precrop_steps': {NN}, 'max_steps': {P}, 'lr_init': {F, P}, 'lr_final': {F, P},
    'lr_delay_steps': {NN}, 'max_skipped_steps': {P}, 'stuck_warning_steps': {NN}, 'freq_reg_end': {NN},
    'occ_reg_range': {NN}, 'occ_wb_range': {NN}, 'n_random_poses': {P}, 'anneal_nearfar_steps': {P},
    'eval_factor': {P}, 'curve_every': {NN}, 'curve_spread_views': {NN}, 'curve_factor': {P},
    'depth_rank_loss_mult': {NN}, 'depth_rank_margin': {NN}, 'depth_pearson_loss_mult': {NN},
    'depth_patch_size': {P}, 'depth_prior_rays': {P}, 'sfm_depth_loss_mult': {NN},
    'camera_lr_init': {F, P}, 'camera_lr_final': {F, P}, 'camera_lr_delay_steps': {NN}, 'camera_adam_eps': {F, P},
    'coarse_to_fine_start': {F, NN}, 'coarse_to_fine_end': {F, P},
    'camera_noise_rotation_deg': {F, NN}, 'camera_noise_translation': {F, NN}, 'test_pose_steps': {NN},
    'test_pose_lr': {F, P}}


def test_each_field_declares_exactly_the_ranges_the_table_expects():
  declared = {f.name: set(f.metadata['properties']) & set(configs.RANGES) for f in FIELDS}
  assert {name: ranges for name, ranges in declared.items() if ranges} == EXPECTED_RANGES


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
@pytest.mark.parametrize('name', configs.declared(configs.SEED))
def test_a_seed_no_random_generator_takes_is_refused_naming_it(name, value):
  with pytest.raises(ValueError, match=re.escape(f'Config.{name} = {value}; expected a whole number in [0, 2^63)')):
    config_loader.validate(dataclasses.replace(Config(), **{name: value}))
  config_loader.validate(dataclasses.replace(Config(), **{name: 2**63 - 1}))
