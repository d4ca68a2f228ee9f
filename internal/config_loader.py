"""Reading a Config from .gin files and bindings, and checking every setting before any work."""

import ast
import contextlib
import dataclasses
import logging
import math
import os
import re
import warnings
from typing import Sequence

import gin
import numpy as np

from internal import configs
from internal.configs import Config
from internal.models import coarse_to_fine
from internal.models import freq_schedule
from internal.models import gaussians
from internal.evaluation import lpips
from internal.models import mip_nerf
from internal.models import nerf
from internal.models import registry
from internal.models import precision
from internal.models import sampling
from internal.training import train_step
from internal.datasets import base
from internal.datasets import batching
from internal.datasets import depth_prior
from internal.datasets import image_io
from internal.datasets import loader
from internal.cameras import caster


# `include 'configs/common/...'` in the repository's configs resolves from any working directory.
gin.add_config_file_search_path(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# Model fields set from Config (gin refuses bindings of them), e.g. the background the data and renderer share.
SET_FROM_CONFIG = configs.declared(configs.TO_MODEL)
# How gin names Config in the bindings it records.
CONFIG_SELECTOR = gin.config.ParsedBindingKey.parse(('', 'Config', 'expname')).complete_selector


def parse_gin(gin_configs: Sequence[str] = (), gin_bindings: Sequence[str] = ()) -> tuple:
  """Parses .gin files and bindings; unknown bindings raise, naming the binding. Returns the Config fields they
  bind, in the order gin binds them (files and their includes in order, then the bindings; repeats kept)."""
  for path in gin_configs:
    if not os.path.isfile(path):
      raise FileNotFoundError(f'gin config {path!r} does not exist')
  logging.root.addFilter(_not_gin_path_noise)
  try:
    with _config_bindings_in_order() as bound:
      gin.parse_config_files_and_bindings(list(gin_configs), list(gin_bindings), skip_unknown=False)
    return tuple(bound)
  except SyntaxError as err:  # gin reports a malformed value as a SyntaxError; it is a bad setting.
    raise ValueError(f'cannot parse the gin configs {list(gin_configs)} / bindings {list(gin_bindings)}: '
                     f'{err}') from err
  except OSError as err:
    _raise_missing_include(err)
    raise
  except ValueError as err:
    for name in SET_FROM_CONFIG:
      if f"denylisted kwarg '{name}'" in str(err):
        raise ValueError(f'{str(err).splitlines()[-1].strip()}: the model\'s {name} is set from Config.{name}, '
                         f'the one setting of it; bind Config.{name} instead') from err
    raise
  finally:
    logging.root.removeFilter(_not_gin_path_noise)


@contextlib.contextmanager
def _config_bindings_in_order():
  """Yields a list that collects the name of each Config field gin binds (unscoped, as Config() reads them) while
  the context is open, in order: gin keeps only each binding's last value, not which of two came last."""
  bound, bind = [], gin.config.bind_parameter

  def recording_bind(binding_key, value):
    bind(binding_key, value)
    key = gin.config.ParsedBindingKey.parse(binding_key)
    if key.config_key == ('', CONFIG_SELECTOR):
      bound.append(key.arg_name)

  gin.config.bind_parameter = recording_bind
  try:
    yield bound
  finally:
    gin.config.bind_parameter = bind


def _not_gin_path_noise(record: logging.LogRecord) -> bool:
  """False for gin's 'Path not found' log line of each place it looked for an include (the error names them)."""
  return not record.getMessage().startswith('Path not found: ')


def _raise_missing_include(err: OSError) -> None:
  """Raises FileNotFoundError naming the gin file, its line and the include that gin could not open (if so)."""
  missing = re.search(r'Unable to open file: (.+?)\. Searched config paths: (\[.*?\])', str(err))
  where = re.search(r'In file "(.+?)", line (\d+)', str(err))  # The innermost including file comes first.
  if missing and where:
    searched = list(dict.fromkeys(path or os.getcwd() for path in ast.literal_eval(missing.group(2))))
    raise FileNotFoundError(f'gin config {where.group(1)!r}, line {where.group(2)}: include {missing.group(1)!r} '
                            f'does not exist (looked for it in {searched})') from err


def load_config(gin_configs: Sequence[str] = (), gin_bindings: Sequence[str] = (), backend: str = '') -> Config:
  """Parses gin and returns a validated Config, its precision resolved for backend ('' = this process's)."""
  bound = parse_gin(gin_configs, gin_bindings)
  config = _expand_home(_resolve_freq_reg_end(_apply_warmup_end(_current_loader_name(Config())), bound))
  validate(config)
  # Concrete from here on: a run records (and its fingerprint checks) the numerics it trained with.
  return dataclasses.replace(config, precision=precision.resolve(config.precision, backend))


# The Config fields that name a file or folder: a leading '~' means a home folder, as in a shell.
PATH_FIELDS = configs.declared(configs.PATH)


def _expand_home(config: Config) -> Config:
  """Config with '~' and '~user' at the start of its PATH_FIELDS expanded; ValueError naming one it cannot."""
  expanded = {name: os.path.expanduser(getattr(config, name)) for name in PATH_FIELDS}
  for name, path in expanded.items():
    if path.startswith('~'):
      raise ValueError(f'Config.{name} = {path!r}: no home folder of user {path[1:].split(os.sep)[0]!r} to '
                       "expand '~' with; expected a path without '~' or with a known user's")
  return dataclasses.replace(config, **expanded)


def _current_loader_name(config: Config) -> Config:
  """Config with an earlier name of its loader (loader.RENAMED) replaced by the current one, with a warning."""
  name = loader.RENAMED.get(config.dataset_loader)
  if name is None:
    return config
  warnings.warn(f'Config.dataset_loader = {config.dataset_loader!r} is an earlier name of {name!r}: read as '
                f'{name!r} (write that in your gin files)', stacklevel=3)
  return dataclasses.replace(config, dataset_loader=name)


def _apply_warmup_end(config: Config) -> Config:
  """Config with freq_reg_end taken from the released alias warmup_end when only the alias is set."""
  if config.warmup_end and config.freq_reg_end and config.warmup_end != config.freq_reg_end:
    raise ValueError(f'Config.warmup_end = {config.warmup_end} (an older name of Config.freq_reg_end) '
                     f'conflicts with Config.freq_reg_end = {config.freq_reg_end}; set only one')
  if config.warmup_end and not config.freq_reg_end:
    return dataclasses.replace(config, freq_reg_end=config.warmup_end)
  return config


def _last(bound: Sequence[str], name: str) -> int:
  """Position of the last binding of Config.<name> in bound (parse_gin's order), -1 when none binds it."""
  return max((i for i, b in enumerate(bound) if b == name), default=-1)


def _resolve_freq_reg_end(config: Config, bound: Sequence[str]) -> Config:
  """Config with freq_reg_end = round(freq_reg_end_fraction x max_steps) when a fraction is set and bound after
  the last freq_reg_end (bound: the Config fields in the order gin bound them; the later setting wins, as gin's
  own rule); a fraction that is negative or not finite is a ValueError."""
  fraction = config.freq_reg_end_fraction
  if fraction is None:
    return config
  if _last(bound, 'freq_reg_end') > _last(bound, 'freq_reg_end_fraction'):
    return dataclasses.replace(config, freq_reg_end_fraction=None)
  if isinstance(fraction, bool) or not (isinstance(fraction, (int, float)) and math.isfinite(fraction) and fraction >= 0):
    raise ValueError(f'Config.freq_reg_end_fraction = {fraction!r}; expected a finite number >= 0 (T as a '
                     'fraction of Config.max_steps), or None')
  return dataclasses.replace(config, freq_reg_end=round(fraction * config.max_steps))


# Settings that name one of a list of options, each list next to the code that implements it.
CONFIG_CHOICES = loader.SETTING_CHOICES + (
    ('downsample_mode', image_io.DOWNSAMPLE_MODES), ('batching', batching.BATCHING_MODES),
    ('nonfinite_grad_policy', train_step.NONFINITE_POLICIES), ('lpips_input_range', lpips.INPUT_RANGES),
    ('precision', precision.CHOICES), ('model', tuple(registry.MODELS)))
MODEL_CHOICES = (('ray_shape', gaussians.RAY_SHAPES), ('pdf_padding', sampling.PDF_PADDINGS))


def validate(config: Config) -> None:
  """Raises a ValueError naming the setting when a value is out of range."""
  for name, options in CONFIG_CHOICES:
    base.check_choice(f'Config.{name}', getattr(config, name), options, ValueError)
  model = mip_nerf.MipNerfModel()
  for name, options in MODEL_CHOICES:
    base.check_choice(f'MipNerfModel.{name}', getattr(model, name), options, ValueError)
  _check_types(config)
  _check_ranges(config)
  _check_seeds(config)
  _check_generated_size(config.generated_size)
  _check_model_settings(config.model)
  if config.far <= config.near:
    raise ValueError(f'Config.far = {config.far} must exceed Config.near = {config.near}')
  if loader.ndc(config) is False and config.near <= 0.:
    raise ValueError(f'Config.near = {config.near}; expected > 0 for {config.dataset_loader!r} scenes, whose rays '
                     'start in world space (only LLFF-style NDC rays start at 0)')
  _check_ndc_near_far(config)
  if not 0. < config.precrop_frac <= 1.:
    raise ValueError(f'Config.precrop_frac = {config.precrop_frac}; expected a fraction in (0, 1]')
  freq_schedule.check_settings(config, registry.build(config.model).encoding_degrees())
  coarse_to_fine.check_settings(config)
  _warn_on_unused_regularizer(config)
  _validate_regnerf(config)
  _validate_curve(config)
  _validate_blender_code_settings(config)
  depth_prior.check_settings(config)


def _check_ranges(config: Config) -> None:
  """Raises a ValueError naming the first setting outside a range it declares (configs.RANGES, then its at_most),
  with its hint."""
  fields = dataclasses.fields(Config)
  checks = [(kind, f) for kind in configs.RANGES for f in fields if kind in f.metadata['properties']]
  for kind, field in checks + [(AT_MOST, f) for f in fields if f.metadata['at_most'] is not None]:
    value = getattr(config, field.name)
    expected = _outside(kind, value, field)
    if expected:
      hint = f' ({field.metadata["hint"]})' if field.metadata['hint'] else ''
      raise ValueError(f'Config.{field.name} = {value}; expected {expected}{hint}')


# Training computes in float32: a float setting must be a number it holds, a positive one a normal number (XLA
# flushes smaller ones to 0 on CPUs).
FLOAT32_MAX, FLOAT32_TINY = float(np.finfo(np.float32).max), float(np.finfo(np.float32).tiny)
AT_MOST = 'at_most'  # The check of a field's at_most (configs.setting), after its RANGES.


def _outside(kind: str, value, field: dataclasses.Field) -> str:
  """What a value of field outside a declared range (or at_most) is expected to be ('' when it is inside)."""
  if kind == AT_MOST:
    return '' if value <= field.metadata['at_most'] else f'<= {field.metadata["at_most"]:g}'
  if kind == configs.FINITE:
    if isinstance(value, float) and not math.isfinite(value):
      return 'a finite number'
    return '' if abs(value) <= FLOAT32_MAX else f'a finite number float32 holds (|x| <= {FLOAT32_MAX:.4g})'
  if kind == configs.NON_NEGATIVE:
    return '' if value >= 0 else '>= 0'
  if not isinstance(field.default, float):
    return '' if value >= 1 else 'a positive integer'
  if value <= 0:
    return '> 0'
  return '' if value >= FLOAT32_TINY else f'a positive number float32 holds (>= {FLOAT32_TINY:.4g})'


# Seeds jax.random.PRNGKey (int64) and numpy's generators (non-negative) both take.
SEED_LIMIT = 2**63


def seed_expected(seed) -> str:
  """What a seed that a random generator would refuse (numpy's message names no setting) is expected to be ('' when
  both jax's and numpy's take it); each caller names its setting or flag."""
  return '' if 0 <= seed < SEED_LIMIT else "a whole number in [0, 2^63) (a seed of jax's and numpy's random generators)"


def _check_seeds(config: Config) -> None:
  """Raises a ValueError naming the first seed setting (configs.RNG_SEED) that no random generator takes."""
  for name in configs.declared(configs.RNG_SEED):
    value = getattr(config, name)
    expected = seed_expected(value)
    if expected:
      raise ValueError(f'Config.{name} = {value}; expected {expected}')


def _validate_blender_code_settings(config: Config) -> None:
  """Raises a ValueError naming the pixel offset or NeRF initializer (the released Blender code's settings)."""
  if not 0. <= config.pixel_offset < 1.:
    raise ValueError(f'Config.pixel_offset = {config.pixel_offset}; expected in [0, 1) (0.5 = pixel centres, '
                     '0 = integer pixel coordinates)')
  if config.model == 'nerf':
    base.check_choice('NerfMLP.weight_init', nerf.NerfMLP().weight_init, nerf.WEIGHT_INITS, ValueError)


def _check_generated_size(size) -> None:
  """Raises a ValueError naming Config.generated_size unless it is two positive integers (H, W)."""
  if (not isinstance(size, (list, tuple)) or len(size) != 2
      or any(isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in size)):
    raise ValueError(f'Config.generated_size = {size!r}; expected two positive integers (height, width)')


# The model settings that size its network and samples, with their least workable value (below it the model
# cannot be built or trained); each model's and MLP's own, under their gin names.
MODEL_MINIMUMS = {'MipNerfModel': (('num_samples', 1), ('num_levels', 1)),
                  'MLP': (('net_width', 1), ('net_depth_viewdirs', 1), ('net_width_viewdirs', 1)),
                  'NerfModel': (('num_coarse_samples', 1), ('num_fine_samples', 0)),
                  'NerfMLP': (('net_width', 1), ('net_width_viewdirs', 1))}


def _check_model_settings(model: str) -> None:
  """Raises a ValueError naming the binding (e.g. MipNerfModel.num_samples) of a model size out of range, or of
  mip-NeRF's MLP's fused kernel settings that cannot run."""
  for gin_name, module in registry.gin_modules(model):
    for name, minimum in MODEL_MINIMUMS.get(gin_name, ()):
      value = getattr(module, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f'{gin_name}.{name} = {value!r}; expected an integer >= {minimum}')
    if isinstance(module, mip_nerf.MLP):
      module.check_dense_kernel()


def _check_ndc_near_far(config: Config) -> None:
  """Refuses a Config.near/far that NDC rays would ignore: only (0, 1), or both left at their defaults.

  RegNeRF's annealing (Config.anneal_nearfar) reads Config.near/far, so under it only (0, 1) is accepted.
  """
  if not loader.ndc(config):  # World rays (or a pack, whose settings are checked on load).
    return
  fields = {f.name: f.default for f in dataclasses.fields(Config)}
  unset = (config.near, config.far) == (fields['near'], fields['far']) and not config.anneal_nearfar
  if unset or (config.near, config.far) == caster.NDC_NEAR_FAR:
    return
  name, value = ('near', config.near) if config.near != caster.NDC_NEAR_FAR[0] else ('far', config.far)
  why = ' (Config.anneal_nearfar reads them)' if config.anneal_nearfar else ''
  raise ValueError(f'Config.{name} = {value}: {config.dataset_loader!r} scenes use NDC rays, which fix near = 0 '
                   f'and far = 1{why}; set Config.near = 0 and Config.far = 1')


def _check_types(config: Config) -> None:
  """Raises a ValueError naming the setting when a number, flag or name has another type (e.g. near = 'a')."""
  for field in dataclasses.fields(config):
    value, default = getattr(config, field.name), field.default
    if isinstance(default, bool):
      ok, expected = isinstance(value, bool), 'True or False'
    elif isinstance(default, (int, float)):
      ok = isinstance(value, (int, float)) and not isinstance(value, bool)
      ok, expected = ok and (isinstance(value, int) or isinstance(default, float)), type(default).__name__
    elif isinstance(default, str):
      ok, expected = isinstance(value, str), 'a string'
    else:
      continue
    if not ok:
      raise ValueError(f'Config.{field.name} = {value!r}; expected {expected}')


def _warn_on_unused_regularizer(config: Config) -> None:
  """Warns about regularizer settings that are legal but cannot act as written."""
  num_samples = registry.build(config.model).fine_samples_per_ray()
  if config.occ_reg_loss_mult > 0 and config.occ_reg_range > num_samples:
    what = 'MipNerfModel.num_samples' if config.model == 'mipnerf' else 'the fine samples per ray'
    warnings.warn(f'Config.occ_reg_range = {config.occ_reg_range} exceeds {what} = '
                  f'{num_samples}: the occlusion loss covers every sample of the ray', stacklevel=3)


def _validate_regnerf(config: Config) -> None:
  """Raises a ValueError naming the RegNeRF setting that is out of range or not implemented."""
  if config.flow_loss_mult != 0:
    raise ValueError(f'Config.flow_loss_mult = {config.flow_loss_mult}: RegNeRF\'s appearance (flow) '
                     'regularizer was never released and is not implemented; expected 0')
  if config.patch_size < 2:
    raise ValueError(f'Config.patch_size = {config.patch_size}; expected >= 2 (the TV loss needs neighbours)')
  if config.batch_size_random < config.patch_size**2 or config.batch_size_random % config.patch_size**2:
    raise ValueError(f'Config.batch_size_random = {config.batch_size_random}; expected a positive multiple of '
                     f'Config.patch_size**2 = {config.patch_size**2}')
  if config.depth_tvnorm_decay and config.depth_tvnorm_maxstep < 1:
    raise ValueError(f'Config.depth_tvnorm_maxstep = {config.depth_tvnorm_maxstep}; expected a positive '
                     'integer when Config.depth_tvnorm_decay = True')


def _validate_curve(config: Config) -> None:
  """Raises a ValueError naming the learning-curve setting that is out of range."""
  ids = config.curve_test_ids
  if (not isinstance(ids, (list, tuple)) or not ids or len(set(ids)) != len(ids)
      or any(isinstance(i, bool) or not isinstance(i, int) or i < 0 for i in ids)):
    raise ValueError(f'Config.curve_test_ids = {ids!r}; expected a non-empty list of distinct test-view positions '
                     '(integers >= 0)')
  if config.curve_every and config.dataset_loader == 'packed' and config.curve_factor != config.eval_factor:
    raise ValueError(f'Config.curve_factor = {config.curve_factor}: a packed scene holds its test views at '
                     f'Config.eval_factor = {config.eval_factor} only; set Config.curve_factor = '
                     f'{config.eval_factor}')
