"""Run directories: one run per Config.checkpoint_dir, never overwritten silently; gin flags of the scripts.

A run directory holds `config.json` (the settings that change training, compared on every start),
`config.gin` (the operative gin config, human readable and re-parsable), `checkpoints/<step>/` (orbax),
`tensorboard/`, and the outputs of eval.py (`test_preds_step_<step>/`) and render.py (`path_renders_step_<step>/`).
"""

import contextlib
import dataclasses
import json
import os
import shutil
import socket
import time

import gin

from internal import atomic
from internal.models import registry

FINGERPRINT_FILE = 'config.json'
GIN_FILE = 'config.gin'
LOCK_FILE = 'train.lock'  # Held by the training process: {'pid', 'host', 'started'}.
# Config fields that do not change what training computes: they may differ between a run and its resumption.
NOT_FINGERPRINTED = (
    'expname', 'project', 'checkpoint_dir', 'overwrite', 'checkpoint_every', 'checkpoint_keep', 'print_every',
    'train_render_every', 'render_chunk_size', 'data_dir', 'dtu_mask_path', 'allow_missing_test_views',
    'render_factor', 'render_path_frames', 'eval_test_ids', 'eval_factor', 'lpips_weights_path',
    'lpips_input_range', 'compute_lpips', 'max_skipped_steps', 'depth_reference_dir', 'curve_every',
    'curve_test_ids', 'curve_spread_views', 'curve_factor', 'stuck_warning_steps')
# flax bookkeeping fields of the model and its MLP, and precision (set from Config.precision, fingerprinted there).
MODULE_NOT_FINGERPRINTED = ('parent', 'name', 'precision')
# white_background is set from Config.white_background; the MLPs a model holds are fingerprinted as <MLP class>.*.
MODEL_NOT_FINGERPRINTED = MODULE_NOT_FINGERPRINTED + ('white_background', 'mlp', 'coarse_mlp', 'fine_mlp')
UNSET = '<unset>'


class RunDirError(RuntimeError):
  """Config.checkpoint_dir holds something this run must not touch (or lacks what it needs)."""


def _jsonable(value):
  """A JSON-compatible stand-in for a config value (callables by name, tuples as lists)."""
  if callable(value):
    return '@' + getattr(value, '__name__', repr(value))
  return json.loads(json.dumps(value, default=repr))


def _settings(config) -> list:
  """(prefix, object, fingerprinted fields) of Config and of Config.model's modules as gin configures them now."""
  modules = [(prefix, obj, MODEL_NOT_FINGERPRINTED) for prefix, obj in registry.gin_modules(config.model)]
  return [(prefix, obj, [f for f in dataclasses.fields(obj) if f.name not in skip])
          for prefix, obj, skip in [('Config', config, NOT_FINGERPRINTED)] + modules]


def fingerprint(config) -> dict:
  """{'<Config|MLP|MipNerfModel|NerfMLP|NerfModel>.<field>': value} of every setting that changes training."""
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
  """The stored fingerprint of run_dir, or None when it holds none; RunDirError when it is unreadable."""
  path = os.path.join(run_dir, FINGERPRINT_FILE)
  if not os.path.isfile(path):
    return None
  try:
    with open(path) as f:
      stored = json.load(f)
  except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
    stored = err
  if not isinstance(stored, dict):
    raise RunDirError(f'{path!r} is empty or corrupt ({stored}); expected the JSON settings of the run. Set '
                      'Config.overwrite = True to delete that run and start over, or choose another '
                      'Config.checkpoint_dir')
  return stored


def _foreign_entries(run_dir: str) -> list:
  """Entries of run_dir other than the training lock (what makes a folder without config.json foreign)."""
  return [e for e in os.listdir(run_dir) if e != LOCK_FILE] if os.path.isdir(run_dir) else []


def _clear(run_dir: str) -> None:
  """Deletes everything in run_dir except the training lock."""
  for entry in _foreign_entries(run_dir):
    path = os.path.join(run_dir, entry)
    if os.path.isdir(path) and not os.path.islink(path):
      shutil.rmtree(path)
    else:
      os.remove(path)


def _settings_diff(run_dir: str, stored, config) -> str:
  """How config differs from run_dir's stored run ('' when new or the same); RunDirError when it holds no run."""
  if stored is None and _foreign_entries(run_dir):
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} is not empty and holds no run ({FINGERPRINT_FILE} '
                      'is missing); choose another Config.checkpoint_dir')
  return '' if stored is None else differences(stored, config)


def _other_run_error(run_dir: str, diff: str) -> RunDirError:
  return RunDirError(
      f'Config.checkpoint_dir {run_dir!r} holds a run with different settings ({diff}); choose another '
      'Config.checkpoint_dir, or set Config.overwrite = True to delete that run and start over')


def prepare_run_dir(config) -> str:
  """Creates or re-opens Config.checkpoint_dir for training; refuses to touch a different run.

  Same settings: resume. Different settings (or an unreadable config.json): RunDirError unless
  Config.overwrite, which deletes that run. A non-empty directory that is not a run directory is never touched.
  The settings are recorded later, by record_settings, once the run has started.
  """
  run_dir = config.checkpoint_dir
  try:
    stored = read_fingerprint(run_dir)
  except RunDirError:
    if not config.overwrite:
      raise
    _clear(run_dir)
    stored = None
  diff = _settings_diff(run_dir, stored, config)
  if diff:
    if not config.overwrite:
      raise _other_run_error(run_dir, diff)
    _clear(run_dir)
  os.makedirs(run_dir, exist_ok=True)
  return run_dir


def check_trainable(config) -> None:
  """Raises now, touching nothing, the RunDirError that training would raise for another run's Config.checkpoint_dir."""
  run_dir = config.checkpoint_dir
  if config.overwrite or not os.path.isdir(run_dir):
    return
  diff = _settings_diff(run_dir, read_fingerprint(run_dir), config)
  if diff:
    raise _other_run_error(run_dir, diff)


def record_settings(run_dir: str, config) -> None:
  """Writes config.json (once: the run's settings) and config.gin (the operative gin config), atomically."""
  path = os.path.join(run_dir, FINGERPRINT_FILE)
  if not os.path.isfile(path):
    atomic.write_text(path, json.dumps(fingerprint(config), indent=1, sort_keys=True))
  atomic.write_text(os.path.join(run_dir, GIN_FILE), gin.operative_config_str())


def _read_lock(path: str):
  """The holder recorded in a lock file ({'pid', 'host', 'started'}), None if it vanished, {} if unreadable."""
  try:
    with open(path) as f:
      holder = json.load(f)
  except FileNotFoundError:
    return None
  except (OSError, UnicodeDecodeError, json.JSONDecodeError):
    return {}
  return holder if isinstance(holder, dict) else {}


def _is_stale(holder: dict) -> bool:
  """True when the holder ran on this host and its process is gone."""
  if holder.get('host') != socket.gethostname() or not isinstance(holder.get('pid'), int):
    return False
  try:
    os.kill(holder['pid'], 0)
  except ProcessLookupError:
    return True
  except PermissionError:  # Alive, under another user.
    return False
  return False


def _acquire(path: str, holder: dict) -> None:
  """Creates the lock file holding holder (complete before it appears); takes over a stale one once."""
  for attempt in range(2):
    tmp = f'{path}.{os.getpid()}.tmp'
    atomic.write_text(tmp, json.dumps(holder))
    try:
      os.link(tmp, path)  # Fails if the lock exists; a hard link makes it appear with its content.
      return
    except FileExistsError:
      current = _read_lock(path)
    finally:
      os.unlink(tmp)
    if current is None or (attempt == 0 and _is_stale(current)):
      with contextlib.suppress(FileNotFoundError):
        os.remove(path)
      continue
    who = (f"process {current.get('pid')} on host {current.get('host')!r}, started {current.get('started')}"
           if current else 'an unreadable lock')
    raise RunDirError(f'Config.checkpoint_dir {os.path.dirname(path)!r} is being trained by {who} ({path!r}); '
                      'wait for it to finish, or delete the lock file if that process is gone')
  raise RunDirError(f'could not take the training lock {path!r}; another process is taking it at the same time')


def _require_not_file(run_dir: str) -> None:
  """RunDirError naming Config.checkpoint_dir when it is an existing file, not a directory."""
  if os.path.exists(run_dir) and not os.path.isdir(run_dir):
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} is an existing file; expected a directory (a new one is '
                      'created, an existing run directory is resumed)')


def _unwritable(run_dir: str, err: OSError) -> RunDirError:
  """The one-line error of a run directory that cannot be created or written (read-only, under a file, ...)."""
  where = f' ({err.filename!r})' if err.filename else ''
  return RunDirError(f'Config.checkpoint_dir {run_dir!r} cannot be written: {err.strerror or err}{where}; expected '
                     'a writable directory (or a new one in a writable folder)')


@contextlib.contextmanager
def open_run(config):
  """prepare_run_dir under an exclusive lock file (<run>/train.lock) held until the block ends; yields run_dir.

  A second training of the same directory gets a RunDirError naming the holder; the lock of a killed process
  (pid gone on this host) is taken over. A file, or a directory that cannot be written, is a RunDirError too.
  """
  run_dir = config.checkpoint_dir
  _require_not_file(run_dir)
  if read_fingerprint(run_dir) is None and _foreign_entries(run_dir):
    prepare_run_dir(config)  # Raises: never put a lock into a foreign folder.
  path = os.path.join(run_dir, LOCK_FILE)
  holder = {'pid': os.getpid(), 'host': socket.gethostname(), 'started': time.strftime('%Y-%m-%d %H:%M:%S %z')}
  try:
    os.makedirs(run_dir, exist_ok=True)
    _acquire(path, holder)
  except OSError as err:
    raise _unwritable(run_dir, err) from err
  try:
    yield prepare_run_dir(config)
  finally:
    if _read_lock(path) == holder:
      os.remove(path)


def check_run_dir(config) -> str:
  """Config.checkpoint_dir for eval/render: it must hold a run trained with the same settings."""
  run_dir = config.checkpoint_dir
  _require_not_file(run_dir)
  stored = read_fingerprint(run_dir)
  if stored is None:
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} holds no run ({FINGERPRINT_FILE} is missing); '
                      'train first with the same --gin_configs')
  diff = differences(stored, config)
  if diff:
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} was trained with different settings ({diff}); pass '
                      'the gin configs and bindings used for training')
  return run_dir
