"""Run directories: one run per Config.checkpoint_dir, never overwritten silently; gin flags of the scripts.

A run directory holds `config.json` (the settings that change training, compared on every start),
`config.gin` (the operative gin config, human readable and re-parsable), `checkpoints/<step>/` (orbax),
`tensorboard/`, and the outputs of eval.py (`test_preds_step_<step>/`) and render.py (`path_renders_step_<step>/`).
"""

import argparse
import dataclasses
import json
import os
import shutil

import gin

from internal import configs
from internal import models

DEMO_CONFIG = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'configs', 'demo.gin')
FINGERPRINT_FILE = 'config.json'
GIN_FILE = 'config.gin'
# Config fields that do not change what training computes: they may differ between a run and its resumption.
NOT_FINGERPRINTED = (
    'expname', 'project', 'checkpoint_dir', 'overwrite', 'checkpoint_every', 'checkpoint_keep', 'print_every',
    'train_render_every', 'render_chunk_size', 'data_dir', 'dtu_mask_path', 'allow_missing_test_views',
    'render_factor', 'render_path_frames', 'eval_test_ids', 'eval_factor', 'lpips_weights_path',
    'lpips_input_range', 'compute_lpips')
# flax bookkeeping fields of MLP and MipNerfModel, and precision (set from Config.precision, fingerprinted there).
MODULE_NOT_FINGERPRINTED = ('parent', 'name', 'precision')
MODEL_NOT_FINGERPRINTED = MODULE_NOT_FINGERPRINTED + ('white_background',)  # Set from Config.white_background.
UNSET = '<unset>'


class RunDirError(RuntimeError):
  """Config.checkpoint_dir holds something this run must not touch (or lacks what it needs)."""


def _jsonable(value):
  """A JSON-compatible stand-in for a config value (callables by name, tuples as lists)."""
  if callable(value):
    return '@' + getattr(value, '__name__', repr(value))
  return json.loads(json.dumps(value, default=repr))


def _settings(config) -> list:
  """(prefix, object, fingerprinted fields) of Config and of the model modules as gin configures them now."""
  return [(prefix, obj, [f for f in dataclasses.fields(obj) if f.name not in skip])
          for prefix, obj, skip in (('Config', config, NOT_FINGERPRINTED),
                                    ('MLP', models.MLP(), MODULE_NOT_FINGERPRINTED),
                                    ('MipNerfModel', models.MipNerfModel(), MODEL_NOT_FINGERPRINTED))]


def fingerprint(config) -> dict:
  """{'<Config|MLP|MipNerfModel>.<field>': value} of every setting that changes training."""
  return {f'{prefix}.{f.name}': _jsonable(getattr(obj, f.name))
          for prefix, obj, fields in _settings(config) for f in fields}


def _stored_view(stored: dict, config) -> dict:
  """stored, completed with the defaults of fields added to the code after that run was started."""
  defaults = {f'{prefix}.{f.name}': _jsonable(f.default) for prefix, _, fields in _settings(config)
              for f in fields if f.default is not dataclasses.MISSING}
  return {**defaults, **stored}


def differences(stored: dict, config) -> str:
  """'name: stored -> current; ...' for up to 5 settings that differ ('' when none)."""
  stored, current = _stored_view(stored, config), fingerprint(config)
  names = sorted(k for k in set(stored) | set(current) if stored.get(k, UNSET) != current.get(k, UNSET))
  parts = [f'{k}: {stored.get(k, UNSET)!r} -> {current.get(k, UNSET)!r}' for k in names[:5]]
  more = f' (and {len(names) - 5} more)' if len(names) > 5 else ''
  return '; '.join(parts) + more


def read_fingerprint(run_dir: str):
  """The stored fingerprint of run_dir, or None when it holds none."""
  path = os.path.join(run_dir, FINGERPRINT_FILE)
  if not os.path.isfile(path):
    return None
  with open(path) as f:
    return json.load(f)


def prepare_run_dir(config) -> str:
  """Creates or re-opens Config.checkpoint_dir for training; refuses to touch a different run.

  Same settings: resume. Different settings: RunDirError unless Config.overwrite, which deletes that run.
  A non-empty directory that is not a run directory is never touched.
  """
  run_dir = config.checkpoint_dir
  stored = read_fingerprint(run_dir)
  if stored is None and os.path.isdir(run_dir) and os.listdir(run_dir):
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} is not empty and holds no run ({FINGERPRINT_FILE} '
                      'is missing); choose another Config.checkpoint_dir')
  diff = '' if stored is None else differences(stored, config)
  if diff:
    if not config.overwrite:
      raise RunDirError(
          f'Config.checkpoint_dir {run_dir!r} holds a run with different settings ({diff}); choose another '
          'Config.checkpoint_dir, or set Config.overwrite = True to delete that run and start over')
    shutil.rmtree(run_dir)
  os.makedirs(run_dir, exist_ok=True)
  with open(os.path.join(run_dir, FINGERPRINT_FILE), 'w') as f:
    json.dump(fingerprint(config), f, indent=1, sort_keys=True)
  return run_dir


def check_run_dir(config) -> str:
  """Config.checkpoint_dir for eval/render: it must hold a run trained with the same settings."""
  run_dir = config.checkpoint_dir
  stored = read_fingerprint(run_dir)
  if stored is None:
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} holds no run ({FINGERPRINT_FILE} is missing); '
                      'train first with the same --gin_configs')
  diff = differences(stored, config)
  if diff:
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} was trained with different settings ({diff}); pass '
                      'the gin configs and bindings used for training')
  return run_dir


def write_gin_config(run_dir: str) -> None:
  """Writes the operative gin config (every value used so far) to <run_dir>/config.gin."""
  with open(os.path.join(run_dir, GIN_FILE), 'w') as f:
    f.write(gin.operative_config_str())


def flag_parser(description: str) -> argparse.ArgumentParser:
  """An argument parser with --gin_configs / --gin_bindings, each repeatable and taking one or more values."""
  parser = argparse.ArgumentParser(description=description)
  parser.add_argument('--gin_configs', action='extend', nargs='+', default=[], metavar='FILE',
                      help='gin config files, applied in order')
  parser.add_argument('--gin_bindings', action='extend', nargs='+', default=[], metavar='BINDING',
                      help='gin bindings applied after the files, e.g. "Config.freq_reg_end = 20000"')
  return parser


def config_from_flags(args: argparse.Namespace):
  """The validated Config of parsed flags; configs/demo.gin when no --gin_configs was given."""
  return configs.load_config(args.gin_configs or [DEMO_CONFIG], args.gin_bindings)
