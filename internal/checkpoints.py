"""Orbax checkpoints of the TrainState in <run dir>/checkpoints/<step>/ (async saves, keep-N, read-only loads)."""

import os

import jax
from jax import random
import numpy as np
import orbax.checkpoint as ocp

from internal import train_step

CHECKPOINT_SUBDIR = 'checkpoints'


class NoCheckpointError(FileNotFoundError):
  """A run directory holds no checkpoint to evaluate or render."""


def manager(run_dir: str, keep: int) -> ocp.CheckpointManager:
  """An orbax CheckpointManager on <run_dir>/checkpoints keeping the newest `keep` steps (async saves)."""
  options = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
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


def restore_latest(mngr: ocp.CheckpointManager, template):
  """The newest saved TrainState shaped like template, or None when there is none."""
  step = mngr.latest_step()
  return None if step is None else _restore(mngr, step, template)


def load_latest(run_dir: str, template):
  """The newest TrainState of run_dir shaped like template; NoCheckpointError naming the folder if none."""
  step = latest_step(run_dir)
  mngr = reader(run_dir)
  try:
    return _restore(mngr, step, template)
  finally:
    mngr.close()


def latest_step(run_dir: str) -> int:
  """The newest checkpointed step of run_dir; NoCheckpointError naming the folder if there is none."""
  folder = os.path.join(run_dir, CHECKPOINT_SUBDIR)
  step = None
  if os.path.isdir(folder):
    mngr = reader(run_dir)
    step = mngr.latest_step()
    mngr.close()
  if step is None:
    raise NoCheckpointError(f'no checkpoint in {folder!r}; train first with the same --gin_configs')
  return step


def restore_model(config, run_dir: str, example_rays):
  """(model, newest TrainState) of a run, for eval and render; the model is built from Config and gin."""
  model, template = train_step.create_train_state(config, random.PRNGKey(config.jax_rng_seed), example_rays)
  return model, load_latest(run_dir, template)
