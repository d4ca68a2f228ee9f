"""Reading a Config from .gin files and bindings, and checking every setting before any work."""

import dataclasses
import math
import os
import warnings
from typing import Sequence

import gin

from internal.configs import Config
from internal.models import freq_mask
from internal.models import gaussians
from internal.evaluation import lpips
from internal.models import mip_nerf
from internal.models import precision
from internal.models import sampling
from internal.training import train_step
from internal.datasets import batching
from internal.datasets import blender
from internal.datasets import dtu
from internal.datasets import image_io
from internal.datasets import loader
from internal.datasets import raygen
from internal.datasets import synthetic


# `include 'configs/common/...'` in the repository's configs resolves from any working directory.
gin.add_config_file_search_path(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# Model fields set from Config (gin refuses bindings of them), e.g. the background the data and renderer share.
SET_FROM_CONFIG = ('white_background', 'precision')


def parse_gin(gin_configs: Sequence[str] = (), gin_bindings: Sequence[str] = ()) -> None:
  """Parses .gin files and bindings; unknown bindings raise, naming the binding."""
  for path in gin_configs:
    if not os.path.isfile(path):
      raise FileNotFoundError(f'gin config {path!r} does not exist')
  try:
    gin.parse_config_files_and_bindings(list(gin_configs), list(gin_bindings), skip_unknown=False)
  except SyntaxError as err:  # gin reports a malformed value as a SyntaxError; it is a bad setting.
    raise ValueError(f'cannot parse the gin configs {list(gin_configs)} / bindings {list(gin_bindings)}: '
                     f'{err}') from err
  except ValueError as err:
    for name in SET_FROM_CONFIG:
      if f"denylisted kwarg '{name}'" in str(err):
        raise ValueError(f'{str(err).splitlines()[-1].strip()}: the model\'s {name} is set from Config.{name}, '
                         f'the one setting of it; bind Config.{name} instead') from err
    raise


def load_config(gin_configs: Sequence[str] = (), gin_bindings: Sequence[str] = ()) -> Config:
  """Parses gin and returns a validated Config."""
  parse_gin(gin_configs, gin_bindings)
  config = _apply_warmup_end(Config())
  validate(config)
  return config


def _apply_warmup_end(config: Config) -> Config:
  """Config with freq_reg_end taken from the released alias warmup_end when only the alias is set."""
  if config.warmup_end and config.freq_reg_end and config.warmup_end != config.freq_reg_end:
    raise ValueError(f'Config.warmup_end = {config.warmup_end} (an older name of Config.freq_reg_end) '
                     f'conflicts with Config.freq_reg_end = {config.freq_reg_end}; set only one')
  if config.warmup_end and not config.freq_reg_end:
    return dataclasses.replace(config, freq_reg_end=config.warmup_end)
  return config


def _choice(config, name: str, options: Sequence[str], prefix: str = 'Config') -> None:
  """Raises a ValueError naming prefix.name unless the setting is one of options."""
  value = getattr(config, name)
  if value not in options:
    raise ValueError(f'{prefix}.{name} = {value!r}; expected one of {list(options)}')


def validate(config: Config) -> None:
  """Raises a ValueError naming the setting when a value is out of range."""
  # Each option list lives next to the code that implements it.
  _choice(config, 'dataset_loader', loader.LOADERS)
  _choice(config, 'dtu_layout', dtu.LAYOUTS)
  _choice(config, 'blender_split', blender.SPLIT_MODES)
  _choice(config, 'downsample_mode', image_io.DOWNSAMPLE_MODES)
  _choice(config, 'batching', batching.BATCHING_MODES)
  _choice(config, 'freq_mask_layout', freq_mask.LAYOUTS)
  _choice(config, 'nonfinite_grad_policy', train_step.NONFINITE_POLICIES)
  _choice(config, 'lpips_input_range', lpips.INPUT_RANGES)
  _choice(config, 'generated_rig', synthetic.RIGS)
  _choice(config, 'precision', precision.PRECISIONS)
  model = mip_nerf.MipNerfModel()
  _choice(model, 'ray_shape', gaussians.RAY_SHAPES, 'MipNerfModel')
  _choice(model, 'pdf_padding', sampling.PDF_PADDINGS, 'MipNerfModel')
  _check_types(config)
  for name in ('max_steps', 'batch_size', 'render_chunk_size', 'checkpoint_every', 'checkpoint_keep',
               'print_every', 'render_path_frames'):
    if getattr(config, name) < 1:
      raise ValueError(f'Config.{name} = {getattr(config, name)}; expected a positive integer')
  for name in ('n_input_views', 'freq_reg_end', 'occ_reg_range', 'occ_wb_range', 'lr_delay_steps',
               'stuck_warning_steps'):
    if getattr(config, name) < 0:
      raise ValueError(f'Config.{name} = {getattr(config, name)}; expected >= 0')
  if config.max_skipped_steps < 1:
    raise ValueError(f'Config.max_skipped_steps = {config.max_skipped_steps}; expected >= 1')
  if not 0. <= config.max_vis_freq_ratio <= 1.:
    raise ValueError(f'Config.max_vis_freq_ratio = {config.max_vis_freq_ratio}; expected in [0, 1]')
  if config.far <= config.near:
    raise ValueError(f'Config.far = {config.far} must exceed Config.near = {config.near}')
  for name in ('near', 'far', 'lr_init', 'lr_final'):
    if not math.isfinite(getattr(config, name)):
      raise ValueError(f'Config.{name} = {getattr(config, name)}; expected a finite number')
  for name in ('lr_init', 'lr_final'):
    if getattr(config, name) <= 0.:
      raise ValueError(f'Config.{name} = {getattr(config, name)}; expected > 0 (the learning rate decays '
                       'log-linearly from lr_init to lr_final)')
  if needs_positive_near(config) and config.near <= 0.:
    raise ValueError(f'Config.near = {config.near}; expected > 0 for {config.dataset_loader!r} scenes, whose rays '
                     'start in world space (only LLFF-style NDC rays start at 0)')
  _check_ndc_near_far(config)
  if config.max_vis_freq_ratio > 0 and not config.freq_reg:
    raise ValueError(f'Config.max_vis_freq_ratio = {config.max_vis_freq_ratio} acts only under the frequency '
                     'regularizer, as released; set Config.freq_reg = True (with Config.freq_reg_end = 0 for the '
                     'fixed visible ratio alone) or leave the ratio at 0')
  _warn_on_unused_regularizer(config)
  _validate_regnerf(config)


def needs_positive_near(config: Config) -> bool:
  """True for world-space rays (DTU, Blender, the generated object rig); LLFF's NDC rays ignore Config.near."""
  return config.dataset_loader in ('dtu', 'blender') or (
      config.dataset_loader == 'generated' and config.generated_rig == 'object')


def uses_ndc_rays(config: Config) -> bool:
  """True for LLFF-style NDC rays (LLFF, the generated forward rig): their near and far are fixed at 0 and 1."""
  return config.dataset_loader == 'llff' or (
      config.dataset_loader == 'generated' and config.generated_rig == 'forward')


def _check_ndc_near_far(config: Config) -> None:
  """Refuses a Config.near/far that NDC rays would ignore: only (0, 1), or both left at their defaults.

  RegNeRF's annealing (Config.anneal_nearfar) reads Config.near/far, so under it only (0, 1) is accepted.
  """
  if not uses_ndc_rays(config):
    return
  fields = {f.name: f.default for f in dataclasses.fields(Config)}
  unset = (config.near, config.far) == (fields['near'], fields['far']) and not config.anneal_nearfar
  if unset or (config.near, config.far) == raygen.NDC_NEAR_FAR:
    return
  name, value = ('near', config.near) if config.near != raygen.NDC_NEAR_FAR[0] else ('far', config.far)
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
  if config.freq_reg and config.freq_reg_end > config.max_steps:
    warnings.warn(f'Config.freq_reg_end = {config.freq_reg_end} exceeds Config.max_steps = {config.max_steps}: '
                  'the frequency mask never fully opens during training', stacklevel=3)
  num_samples = mip_nerf.MipNerfModel().num_samples
  if config.occ_reg_loss_mult > 0 and config.occ_reg_range > num_samples:
    warnings.warn(f'Config.occ_reg_range = {config.occ_reg_range} exceeds MipNerfModel.num_samples = '
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
  for name in ('n_random_poses', 'anneal_nearfar_steps'):
    if getattr(config, name) < 1:
      raise ValueError(f'Config.{name} = {getattr(config, name)}; expected a positive integer')
  if config.depth_tvnorm_decay and config.depth_tvnorm_maxstep < 1:
    raise ValueError(f'Config.depth_tvnorm_maxstep = {config.depth_tvnorm_maxstep}; expected a positive '
                     'integer when Config.depth_tvnorm_decay = True')
