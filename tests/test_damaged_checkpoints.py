"""Damaged checkpoints: reported in one line, the newest intact one is used, nothing is deleted; keep-N is safe."""

import glob
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import random_rays
from internal.run import checkpoints
from internal.evaluation import evaluate
from internal.training import train_step
from internal.pipeline import loop
from test_checkpoints import tiny_config

BINDINGS = ('Config.max_steps = 8', 'Config.checkpoint_every = 2', 'Config.compute_lpips = False',
            'Config.eval_test_ids = [0]', 'Config.eval_factor = 4')


@pytest.fixture(scope='module')
def stopped_run(tmp_path_factory, scene_dir):  # pylint: disable=redefined-outer-name
  """A run stopped at step 6 with checkpoints 2, 4, 6."""
  run = tmp_path_factory.mktemp('damaged') / 'run'
  loop.train(tiny_config(scene_dir, run, *BINDINGS), stop_at_step=6)
  return run


def _damage(step_dir, how: str) -> None:
  """Truncates or deletes the data files of a step folder, or empties it."""
  if how == 'empty':
    shutil.rmtree(step_dir)
    os.mkdir(step_dir)
    return
  for path in glob.glob(os.path.join(step_dir, checkpoints.ITEM, '**', 'd', '*'), recursive=True):
    if how == 'truncate':
      os.truncate(path, 10)
    else:
      os.remove(path)


def _copy(run, tmp_path, how='truncate', steps=(6,)):
  """A copy of run with the given steps damaged."""
  copy = tmp_path / 'run'
  shutil.copytree(run, copy)
  for step in steps:
    _damage(copy / checkpoints.CHECKPOINT_SUBDIR / str(step), how)
  return copy


def _template(scene, run):
  """A TrainState at step 0 of the run's config, to restore into."""
  return train_step.create_train_state(tiny_config(scene, run, *BINDINGS), jax.random.PRNGKey(0),
                                       random_rays(0, 8))[1]


@pytest.mark.parametrize('how', ['truncate', 'delete', 'empty'])
def test_readers_report_the_damaged_step_in_one_line_and_use_the_newest_intact(how, stopped_run, scene_dir,
                                                                                tmp_path, capfd):
  run = _copy(stopped_run, tmp_path, how)
  assert checkpoints.damage(str(run / 'checkpoints' / '4')) is None
  assert checkpoints.damage(str(run / 'checkpoints' / '6'))
  assert checkpoints.latest_step(str(run)) == 4
  state = checkpoints.load_latest(str(run), _template(scene_dir, run))
  err = capfd.readouterr().err.strip().splitlines()
  assert int(state.step) == 4 and len(err) == 1, err
  assert err[0].startswith(f"checkpoint step 6 in '{run}/checkpoints/6' is damaged (") and \
      err[0].endswith('); using step 4')
  assert (run / 'checkpoints' / '6').is_dir()  # Readers leave the folder as it is.


def test_eval_falls_back_to_the_newest_intact_checkpoint(stopped_run, scene_dir, tmp_path, capfd):
  run = _copy(stopped_run, tmp_path, 'delete')
  record = evaluate.evaluate(tiny_config(scene_dir, run, *BINDINGS))
  assert record['step'] == 4 and (run / 'test_preds_step_4' / 'metrics.json').is_file()
  assert 'checkpoint step 6 in' in capfd.readouterr().err


def test_training_moves_the_damaged_step_aside_and_resumes_from_the_intact_one(stopped_run, scene_dir, tmp_path,
                                                                               capfd):
  run = _copy(stopped_run, tmp_path, 'truncate')
  result = loop.train(tiny_config(scene_dir, run, *BINDINGS))
  err = [line for line in capfd.readouterr().err.splitlines() if 'damaged' in line]
  aside = glob.glob(str(run / 'checkpoints' / 'damaged_6_*'))
  assert len(err) == 1 and len(aside) == 1 and f'moved it to {aside[0]!r}; resuming from step 4' in err[0]
  assert int(result.state.step) == 8
  assert checkpoints.reader(str(run)).all_steps() == [2, 4, 6, 8]  # Step 6 is trained and saved again.
  assert checkpoints.damage(str(run / 'checkpoints' / '6')) is None


def test_no_intact_checkpoint_is_a_clear_error(stopped_run, scene_dir, tmp_path):
  run = _copy(stopped_run, tmp_path, 'empty', steps=(2, 4, 6))
  folder = f"'{run}/checkpoints'"
  with pytest.raises(checkpoints.NoIntactCheckpointError, match=f'no intact checkpoint in {folder}'):
    checkpoints.latest_step(str(run))
  with pytest.raises(checkpoints.NoIntactCheckpointError, match=f'no intact checkpoint in {folder}: step 6: '):
    loop.train(tiny_config(scene_dir, run, *BINDINGS))
  assert sorted(os.listdir(run / 'checkpoints')) == ['2', '4', '6']  # Nothing moved when nothing is intact.


@pytest.mark.parametrize('keep', [1, 0])
def test_keep_never_deletes_the_checkpoint_just_written(keep, tmp_path):
  mngr = checkpoints.manager(str(tmp_path), keep)
  for step in range(1, 5):
    state = train_step.TrainState(step=jnp.array(step), params={'w': jnp.full(3, float(step))}, opt_state=())
    assert checkpoints.save(mngr, state)
    mngr.wait_until_finished()
    assert mngr.all_steps() == [step] and checkpoints.damage(str(tmp_path / 'checkpoints' / str(step))) is None
  mngr.close()
  restored = checkpoints.load_latest(str(tmp_path), state)
  np.testing.assert_array_equal(restored.params['w'], [4., 4., 4.])
