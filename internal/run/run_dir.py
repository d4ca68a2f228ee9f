"""Run directories: one run per Config.checkpoint_dir, never overwritten silently; gin flags of the scripts.

A run directory holds `freenerf_jax_run.json` (the marker: a run of this project), `config.json` (the settings
that change training, compared on every start), `config.gin` (the operative gin config, human readable and
re-parsable), `checkpoints/<step>/` (orbax), `tensorboard/`, and the outputs of eval.py (`test_preds_step_<step>/`)
and render.py (`path_renders_step_<step>/`) unless Config.output_dir sends them elsewhere.
"""

import contextlib
import dataclasses
import json
import os
import re
import shutil
import socket
import tempfile
import time

import gin

from internal import atomic
from internal import configs
from internal import lock_holders
from internal.datasets import loader
from internal.models import registry

FINGERPRINT_FILE = 'config.json'
GIN_FILE = 'config.gin'
LOCK_FILE = 'train.lock'  # Held by the training process: {'pid', 'host', 'started'}.
# What makes a folder a run of this project (config.json is a name other tools write too): Config.overwrite deletes
# only in such a folder, and only what WRITTEN names.
MARKER_FILE = 'freenerf_jax_run.json'
MARKER = {'run_of': 'FreeNeRF-JAX', 'note': 'A run directory of FreeNeRF-JAX (train.py). Config.overwrite = True '
          'deletes only the files FreeNeRF-JAX wrote here; other files stay.'}
# Runs of versions from before the marker are recognized by their config.json: only this project's settings have
# every key of the form <gin class>.<field>, these among them.
LEGACY_KEY = re.compile(r'(Config|MLP|MipNerfModel|NerfMLP|NerfModel)\.\w+')
LEGACY_KEYS = {'Config.batch_size', 'Config.max_steps', 'Config.lr_init', 'Config.n_input_views'}


def _atomic_tmp(name: str) -> str:
  """The name pattern of atomic.write_text(<name>)'s temporary file, left by a crash (name: a pattern itself)."""
  return rf'\.{name}\.\w+\.tmp'


_OUTPUTS = {pattern: None for pattern in (
    r'(color|depth|opacity)_\d{3,}\.png', r'depth_\d{3,}\.npz', r'metrics\.(json|csv)', r'render\.json',
    r'.+_(color|depth|opacity)\.mp4', _atomic_tmp(r'metrics\.(json|csv)'), _atomic_tmp(r'render\.json'))}
# What this project writes into a run directory, by the exact form of its names (regular expressions): None deletes
# the entry whole, a dict only the entries of that folder it names (the folder goes when left empty; a link to a
# folder stays, the entries it names in the folder it points to go). Config.overwrite deletes these alone, in this
# order (the settings last, so that an interrupted overwrite still refuses other settings).
WRITTEN = {
    'checkpoints': {r'\d+': None, r'\d+\.orbax-checkpoint-tmp(-\d+)?': None,  # orbax's steps, their temporaries,
                    r'damaged_\d+_\d{8}-\d{6}': None},  # and the damaged ones set aside (checkpoints.py).
    'tensorboard': {r'events\.out\.tfevents\..+': None},
    r'test_preds_step_\d+': _OUTPUTS, r'path_renders_step_\d+': _OUTPUTS,
    r'learning_curve\.csv': None, r'learning_curve_clock\.json': None, re.escape(GIN_FILE): None,
    **{_atomic_tmp(re.escape(name)): None for name in ('learning_curve.csv', 'learning_curve_clock.json', GIN_FILE,
                                                       FINGERPRINT_FILE)},
    re.escape(FINGERPRINT_FILE): None}
# Config fields that do not change what training computes: they may differ between a run and its resumption.
NOT_FINGERPRINTED = configs.declared(configs.BOOKKEEPING)
# Of the model and its MLPs: flax's bookkeeping fields, the MLPs a model holds (fingerprinted as <MLP class>.*) and
# the fields set from Config (fingerprinted there, e.g. Config.precision).
MODEL_NOT_FINGERPRINTED = ('parent', 'name', 'mlp', 'coarse_mlp', 'fine_mlp') + configs.declared(configs.TO_MODEL)
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
  """stored, completed with the defaults of fields added to the code after that run was started, its loader under
  its current name."""
  defaults = {f'{prefix}.{f.name}': _jsonable(f.default) for prefix, _, fields in _settings(config)
              for f in fields if f.default is not dataclasses.MISSING}
  view = {**defaults, **stored}
  name = view.get('Config.dataset_loader')
  return {**view, 'Config.dataset_loader': loader.RENAMED.get(name, name)}  # A run from before a loader's rename.


def differences(stored: dict, config) -> str:
  """'name: stored -> current; ...' for up to 5 settings that differ ('' when none)."""
  stored, current = _stored_view(stored, config), fingerprint(config)
  names = sorted(k for k in set(stored) | set(current) if stored.get(k, UNSET) != current.get(k, UNSET))
  parts = [f'{k}: {stored.get(k, UNSET)!r} -> {current.get(k, UNSET)!r}' for k in names[:5]]
  more = f' (and {len(names) - 5} more)' if len(names) > 5 else ''
  return '; '.join(parts) + more


def _read_json(path: str):
  """The JSON value in path; the error when it cannot be read or parsed."""
  try:
    with open(path) as f:
      return json.load(f)
  except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
    return err


def read_fingerprint(run_dir: str):
  """The stored fingerprint of run_dir, or None when it holds none; RunDirError when it is unreadable."""
  path = os.path.join(run_dir, FINGERPRINT_FILE)
  if not os.path.isfile(path):
    return None
  stored = _read_json(path)
  if not isinstance(stored, dict):
    raise RunDirError(f'{path!r} is empty or corrupt ({stored}); expected the JSON settings of the run. Set '
                      'Config.overwrite = True to delete that run and start over, or choose another '
                      'Config.checkpoint_dir')
  return stored


def is_marked(run_dir: str) -> bool:
  """True when run_dir holds this project's marker file with its content."""
  marker = _read_json(os.path.join(run_dir, MARKER_FILE))
  return isinstance(marker, dict) and marker.get('run_of') == MARKER['run_of']


def _is_legacy_fingerprint(stored) -> bool:
  """True for settings written by a version of this project from before the marker: no other file has these names."""
  return (isinstance(stored, dict) and LEGACY_KEYS <= stored.keys() and
          all(isinstance(k, str) and LEGACY_KEY.fullmatch(k) for k in stored))


def _entries(run_dir: str) -> list:
  """Entries of run_dir other than the training lock and the marker (none: a folder a new run may use)."""
  return [e for e in os.listdir(run_dir) if e not in (LOCK_FILE, MARKER_FILE)] if os.path.isdir(run_dir) else []


def is_run(folder: str) -> bool:
  """True when folder is a run of this project: its marker, or the settings of an earlier version's run."""
  path = os.path.join(folder, FINGERPRINT_FILE)
  return is_marked(folder) or (os.path.isfile(path) and _is_legacy_fingerprint(_read_json(path)))


def _check_ours(run_dir: str) -> None:
  """RunDirError unless run_dir is new, empty, or a run of this project (its marker, or an earlier version's
  settings): a folder of anything else is never touched, whatever Config.overwrite says."""
  if not _entries(run_dir) or is_run(run_dir):
    return
  path = os.path.join(run_dir, FINGERPRINT_FILE)
  found = (f'its {FINGERPRINT_FILE} is not settings of this project' if os.path.isfile(path) else
           f'it holds {sorted(_entries(run_dir))[:3]}')
  raise RunDirError(f'Config.checkpoint_dir {run_dir!r} is not a run of this project (no {MARKER_FILE}; {found}); '
                    'nothing in it is touched, even with Config.overwrite: choose another Config.checkpoint_dir')


def _mark(run_dir: str) -> None:
  """Writes the marker that makes run_dir a run of this project (once)."""
  if not is_marked(run_dir):
    atomic.write_text(os.path.join(run_dir, MARKER_FILE), json.dumps(MARKER, indent=1))


def _delete(path: str, is_folder: bool) -> None:
  """Deletes a file, a link (never what it points to) or a folder with its content; OSError naming path."""
  try:
    if is_folder:
      shutil.rmtree(path)
    else:
      os.remove(path)
  except OSError as err:  # rmtree names the failing entry relative to the folder it was in.
    raise OSError(err.errno, err.strerror, path) from err


def _written(entries, pattern: str) -> list:
  """The entries whose whole name has the form of pattern (a WRITTEN key)."""
  return [entry for entry in entries if re.fullmatch(pattern, entry)]


def _delete_written(folder: str, patterns: dict) -> None:
  """Deletes the entries of folder that patterns name, pattern by pattern (see WRITTEN); keeps every other one."""
  entries = os.listdir(folder)
  for pattern, inner in patterns.items():
    for entry in _written(entries, pattern):
      path = os.path.join(folder, entry)
      if inner is None:
        _delete(path, os.path.isdir(path) and not os.path.islink(path))
      elif os.path.isdir(path):  # Also through a link (checkpoints/ on another disk): else its steps would resume.
        _delete_written(path, inner)
        if not os.path.islink(path):
          with contextlib.suppress(OSError):
            os.rmdir(path)  # Stays when it holds files this project did not write.


def _clear(run_dir: str) -> None:
  """Deletes what this project wrote into run_dir (its settings last); the user's files, the marker and the
  training lock stay."""
  _delete_written(run_dir, WRITTEN)


def _settings_diff(run_dir: str, config) -> str:
  """How config differs from run_dir's run ('' when new or the same); RunDirError when its settings are unreadable
  or missing while files of a run are there."""
  stored = read_fingerprint(run_dir)
  if stored is not None:
    return differences(stored, config)
  written = [e for p in WRITTEN for e in _written(_entries(run_dir), p)]
  if written:
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} holds files of a run ({sorted(written)[:3]}) but not its '
                      f'settings ({FINGERPRINT_FILE} is missing); set Config.overwrite = True to delete that run and '
                      'start over, or choose another Config.checkpoint_dir')
  return ''


def _other_run_error(run_dir: str, diff: str) -> RunDirError:
  return RunDirError(
      f'Config.checkpoint_dir {run_dir!r} holds a run with different settings ({diff}); choose another '
      'Config.checkpoint_dir, or set Config.overwrite = True to delete that run and start over')


def prepare_run_dir(config) -> str:
  """Creates or re-opens Config.checkpoint_dir for training; refuses to touch a different run.

  Same settings: resume. Different settings (or unreadable ones): RunDirError unless Config.overwrite, which
  deletes what this project wrote there (nothing else). A non-empty folder that is not a run of this project is
  never touched. A run of an earlier version, without the marker, is marked. The settings are recorded later,
  by record_settings, once the run has started.
  """
  run_dir = config.checkpoint_dir
  _check_ours(run_dir)
  try:
    diff = _settings_diff(run_dir, config)
  except RunDirError:
    if not config.overwrite:
      raise
    diff = 'unreadable'
  if diff:
    if not config.overwrite:
      raise _other_run_error(run_dir, diff)
    try:
      _clear(run_dir)
    except OSError as err:  # A read-only part: named, and what was not deleted yet stays (settings last).
      raise _unwritable(run_dir, err) from err
  os.makedirs(run_dir, exist_ok=True)
  if _entries(run_dir):
    _mark(run_dir)
  _require_writable_parts(run_dir)
  return run_dir


def check_trainable(config) -> None:
  """Raises now, touching nothing, the RunDirError that training would raise for Config.checkpoint_dir."""
  run_dir = config.checkpoint_dir
  if not os.path.isdir(run_dir):
    return
  _check_ours(run_dir)
  if config.overwrite:
    return
  diff = _settings_diff(run_dir, config)
  if diff:
    raise _other_run_error(run_dir, diff)


def record_settings(run_dir: str, config) -> None:
  """Writes the marker and config.json (once: the run's settings), then config.gin (the operative gin config).

  Each atomically; the marker first, so that every folder holding our config.json is marked.
  """
  _mark(run_dir)
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
    if current is None or (attempt == 0 and lock_holders.process_gone(current)):
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
  return RunDirError(f'Config.checkpoint_dir {run_dir!r} cannot be written: {_why(err)}; expected '
                     'a writable directory (or a new one in a writable folder)')


@contextlib.contextmanager
def open_run(config):
  """prepare_run_dir under an exclusive lock file (<run>/train.lock) held until the block ends; yields run_dir.

  A second training of the same directory gets a RunDirError naming the holder; the lock of a killed process
  (pid gone on this host) is taken over. A file, or a directory that cannot be written, is a RunDirError too.
  """
  run_dir = config.checkpoint_dir
  _require_not_file(run_dir)
  _check_ours(run_dir)  # Never put a lock into a folder of something else.
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
  _check_ours(run_dir)
  stored = read_fingerprint(run_dir)
  if stored is None:
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} holds no run ({FINGERPRINT_FILE} is missing); '
                      'train first with the same --gin_configs')
  diff = differences(stored, config)
  if diff:
    raise RunDirError(f'Config.checkpoint_dir {run_dir!r} was trained with different settings ({diff}); pass '
                      'the gin configs and bindings used for training')
  _check_output_dir(config)
  return run_dir


def _enclosing_run(folder: str):
  """The run of this project that folder is, or lies inside (real paths), or None."""
  path = os.path.realpath(folder)
  while not is_run(path):
    if os.path.dirname(path) == path:
      return None
    path = os.path.dirname(path)
  return path


def _check_output_dir(config) -> None:
  """RunDirError when Config.output_dir lies in a run other than Config.checkpoint_dir's: its outputs would go
  where that run's own evaluations and renders go."""
  other = _enclosing_run(config.output_dir) if config.output_dir else None
  if other and other != os.path.realpath(config.checkpoint_dir):
    raise RunDirError(f'Config.output_dir {config.output_dir!r} is inside {other!r}, another run of this project: '
                      'its test_preds_step_<step>/ and path_renders_step_<step>/ would mix with that run\'s own; '
                      'choose a folder outside other runs (or leave Config.output_dir empty to write into this run)')


def outputs_root(config) -> str:
  """Where eval.py and render.py write: Config.output_dir, or the run directory when it is ''."""
  return config.output_dir or config.checkpoint_dir


def _probe_write(folder: str) -> None:
  """Creates folder if needed and a file in it (deleted at once); OSError when it cannot be written."""
  os.makedirs(folder, exist_ok=True)
  try:
    with tempfile.TemporaryFile(dir=folder):
      pass
  except OSError as err:  # Its filename is the probe's random name: name the folder instead.
    raise OSError(err.errno, err.strerror, folder) from err


def _why(err: OSError) -> str:
  """'<reason> (<file>)' of an OSError."""
  return f'{err.strerror or err}' + (f' ({err.filename!r})' if err.filename else '')


def _require_writable_parts(run_dir: str) -> None:
  """RunDirError naming the first existing folder of run_dir that training writes into but cannot."""
  for name in ('checkpoints', 'tensorboard'):
    folder = os.path.join(run_dir, name)
    if os.path.isdir(folder):
      try:
        _probe_write(folder)
      except OSError as err:
        raise RunDirError(f'{folder!r} in Config.checkpoint_dir cannot be written: {_why(err)}; expected a '
                          'writable folder (training saves into it)') from err


def make_output_folder(config, folder: str) -> None:
  """Creates folder (under outputs_root) and checks it can be written; RunDirError naming the setting if not."""
  try:
    _probe_write(folder)
  except OSError as err:
    why = _why(err)
    if config.output_dir:
      raise RunDirError(f'Config.output_dir {config.output_dir!r} cannot be written: {why}; expected a writable '
                        'folder for the outputs of eval.py and render.py') from err
    raise RunDirError(f'Config.checkpoint_dir {config.checkpoint_dir!r} cannot be written: {why}; set '
                      'Config.output_dir to a writable folder to write the outputs of eval.py and render.py '
                      'there') from err
