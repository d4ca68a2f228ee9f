"""Orbax checkpoints of the TrainState in <run dir>/checkpoints/<step>/ (async saves, keep-N, read-only loads).

A damaged step folder (missing metadata, deleted or truncated data, e.g. from a crash during a save) is reported
in one line and the newest intact checkpoint is used instead; training moves the damaged folder aside to
checkpoints/damaged_<step>_<time> (kept for the user, ignored by orbax) so that later saves are not confused by it.
"""

import json
import os
import sys
import time

import jax
from jax import random
import numpy as np
import orbax.checkpoint as ocp
import tensorstore

from internal import datasets
from internal.run import distributed
from internal.training import camera_refinement
from internal.training import train_step

CHECKPOINT_SUBDIR = 'checkpoints'
ITEM = 'default'  # The folder orbax writes a single StandardSave item to.


class NoCheckpointError(FileNotFoundError):
  """A run directory holds no checkpoint to evaluate or render."""


class NoIntactCheckpointError(NoCheckpointError):
  """Every checkpoint of a run directory is damaged."""


def manager(run_dir: str, keep: int) -> ocp.CheckpointManager:
  """An orbax CheckpointManager on <run_dir>/checkpoints keeping the newest `keep` steps (async saves)."""
  options = ocp.CheckpointManagerOptions(max_to_keep=max(keep, 1), create=True, cleanup_tmp_directories=True)
  return ocp.CheckpointManager(os.path.abspath(os.path.join(run_dir, CHECKPOINT_SUBDIR)), options=options)


def reader(run_dir: str) -> ocp.CheckpointManager:
  """A CheckpointManager on <run_dir>/checkpoints for eval and render: it keeps every step and never saves."""
  options = ocp.CheckpointManagerOptions(max_to_keep=None, create=False)
  return ocp.CheckpointManager(os.path.abspath(os.path.join(run_dir, CHECKPOINT_SUBDIR)), options=options)


def nonfinite_leaves(tree) -> list:
  """Key paths of the leaves of tree holding NaN or Inf (fetched to the host)."""
  return [jax.tree_util.keystr(path) for path, x in jax.tree_util.tree_leaves_with_path(jax.device_get(tree))
          if not np.all(np.isfinite(x))]


def save(mngr: ocp.CheckpointManager, state) -> bool:
  """Starts an async save of TrainState at its step unless that step is already saved; True if started.

  Raises NonFiniteError, writing nothing, when a value of the state is not finite.
  """
  step = int(state.step)
  if step in mngr.all_steps():
    return False
  bad = nonfinite_leaves(state)
  if bad:
    raise train_step.NonFiniteError(f'step {step}: refusing to save a checkpoint with non-finite values in '
                                    f'{", ".join(bad[:3])}{" ..." if len(bad) > 3 else ""}')
  return mngr.save(step, args=ocp.args.StandardSave(state))


def _restore(mngr: ocp.CheckpointManager, step: int, template):
  """The TrainState saved at step, with the tree structure, shapes and dtypes of template."""
  abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, template)
  return mngr.restore(step, args=ocp.args.StandardRestore(abstract))


def damage(step_dir: str):
  """Why the checkpoint in step_dir is unreadable (missing metadata, missing or truncated data), or None.

  Reading every stored value up front turns damage into one clear reason instead of orbax's asynchronous errors.
  """
  item = os.path.join(step_dir, ITEM)
  try:
    for path in (os.path.join(step_dir, '_CHECKPOINT_METADATA'), os.path.join(item, '_METADATA')):
      with open(path) as f:
        json.load(f)
    store = tensorstore.KvStore.open({'driver': 'ocdbt', 'base': f'file://{os.path.abspath(item)}/'}).result()
    for key in store.list().result():
      if not store.read(key).result().value:
        return f'no data for {key.decode()}'
  except (OSError, ValueError) as e:
    return str(e).split('\n')[0]
  return None


def _newest_intact(mngr: ocp.CheckpointManager, load):
  """(step, load(step), [(step, reason) of newer damaged steps]) of the newest checkpoint that load can read.

  (None, None, []) when there is no checkpoint; NoIntactCheckpointError naming the folder when all are damaged.
  """
  damaged = []
  for step in sorted(mngr.all_steps(), reverse=True):
    reason = damage(os.path.join(mngr.directory, str(step)))
    if reason is None:
      try:
        return step, load(step), damaged
      except Exception as e:  # pylint: disable=broad-except  (orbax and tensorstore raise bare Exceptions)
        reason = str(e).split('\n')[0]
    damaged.append((step, reason))
  if damaged:
    raise NoIntactCheckpointError(f'no intact checkpoint in {os.fspath(mngr.directory)!r}: ' + '; '.join(
        f'step {step}: {reason}' for step, reason in damaged))
  return None, None, []


def _report(folder: str, step: int, reason: str, action: str) -> None:
  """One line on stderr about a damaged checkpoint."""
  print(f'checkpoint step {step} in {folder!r} is damaged ({reason}); {action}', file=sys.stderr)


def _set_aside_damaged(mngr: ocp.CheckpointManager) -> int:
  """Moves step folders newer than the newest intact one aside (reported); returns that step (-1: none)."""
  step, _, damaged = _newest_intact(mngr, lambda step: None)
  for bad, reason in damaged:
    folder = os.path.join(os.fspath(mngr.directory), str(bad))
    aside = os.path.join(os.fspath(mngr.directory), f'damaged_{bad}_{time.strftime("%Y%m%d-%H%M%S")}')
    os.rename(folder, aside)
    _report(folder, bad, reason, f'moved it to {aside!r}; resuming from step {step}')
  return -1 if step is None else step


def restore_latest(mngr: ocp.CheckpointManager, template):
  """The newest intact TrainState shaped like template (None when there is none), for training.

  Newer damaged step folders are moved aside to damaged_<step>_<time> and reported, by process 0 alone; every
  process then restores the step process 0 chose (orbax restores are collective).
  """
  step = distributed.on_primary(lambda: _set_aside_damaged(mngr), 'checking the checkpoints')
  step = distributed.max_over_processes(-1 if step is None else step)
  mngr.reload()
  return None if step < 0 else _restore(mngr, step, template)


def load_latest(run_dir: str, template):
  """The newest intact TrainState of run_dir shaped like template (damaged newer ones are reported, left as is).

  NoCheckpointError naming the folder if there is none.
  """
  latest_step(run_dir)  # Names the folder when it holds no checkpoint at all.
  mngr = reader(run_dir)
  try:
    step, state, damaged = _newest_intact(mngr, lambda step: _restore(mngr, step, template))
  finally:
    mngr.close()
  for bad, reason in damaged:
    _report(os.path.join(run_dir, CHECKPOINT_SUBDIR, str(bad)), bad, reason, f'using step {step}')
  return state


def latest_step(run_dir: str) -> int:
  """The newest step of run_dir whose checkpoint looks intact; NoCheckpointError naming the folder if none."""
  folder = os.path.join(run_dir, CHECKPOINT_SUBDIR)
  steps = []
  if os.path.isdir(folder):
    mngr = reader(run_dir)
    steps = mngr.all_steps()
    mngr.close()
  if not steps:
    raise NoCheckpointError(f'no checkpoint in {folder!r}; train first with the same --gin_configs')
  intact = [step for step in steps if damage(os.path.join(folder, str(step))) is None]
  if not intact:
    raise NoIntactCheckpointError(f'no intact checkpoint in {folder!r} (steps {sorted(steps)} are all damaged)')
  return max(intact)


def restore_model(config, run_dir: str, example_rays, train_set=None):
  """(model, newest TrainState) of a run, for eval, render and meshes; the model is built from Config and gin. A run
  that refines its cameras restores their corrections too (train_set: its training split, loaded when None)."""
  cameras = None
  if config.optimize_cameras:
    cameras = camera_refinement.init(config, datasets.load_dataset('train', config) if train_set is None else train_set)
  model, template = train_step.create_train_state(config, random.PRNGKey(config.jax_rng_seed), example_rays, cameras)
  return model, load_latest(run_dir, template)
