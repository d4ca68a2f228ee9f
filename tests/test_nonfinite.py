"""Non-finite values in training runs: skipped updates are counted and reported, never saved, and stop the run."""

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import pytest

from internal import cli
from internal.losses import occlusion
from internal.run import checkpoints
from internal import config_loader
from internal import configs
from internal import datasets
from internal.training import schedule
from internal.training import train_step
from internal.pipeline import loop
from test_checkpoints import DEMO, TINY, tiny_config
import train


def _nan_lr_at(monkeypatch, steps):
  """Makes the learning rate NaN at the given steps (config validation forbids such settings)."""
  original, bad = schedule.config_learning_rate, jnp.array(steps)
  monkeypatch.setattr(schedule, 'config_learning_rate', lambda config, step: jnp.where(
      jnp.any(step == bad), jnp.nan, original(config, step)))


def _nan_data_at(monkeypatch, steps):
  """Makes every target colour of the batches of the given steps NaN."""
  make = datasets.make_batcher

  def make_batcher(dataset, config):
    batcher = make(dataset, config)
    return lambda step: batcher(step)._replace(rgb=np.full((config.batch_size, 3), np.nan, np.float32)) \
        if step in steps else batcher(step)
  monkeypatch.setattr(datasets, 'make_batcher', make_batcher)


def _saved_steps(run_dir) -> list:
  """The checkpointed steps of run_dir, after checking that every value of every checkpoint is finite."""
  mngr = checkpoints.reader(str(run_dir))
  steps = mngr.all_steps()
  for step in steps:
    assert not checkpoints.nonfinite_leaves(mngr.restore(step, args=ocp.args.StandardRestore())), step
  mngr.close()
  return sorted(steps)


def test_skipped_updates_are_counted_reported_and_never_saved(tmp_path, scene_dir, monkeypatch, capsys):
  _nan_lr_at(monkeypatch, [2, 3, 6])
  run = tmp_path / 'run'
  bindings = TINY + [f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'", 'Config.max_steps = 8',
                     'Config.checkpoint_every = 4', 'Config.print_every = 3']
  assert train.main(['--gin_configs', DEMO, '--gin_bindings', *bindings]) == 0
  out = capsys.readouterr().out
  assert 'steps 1-3: 2 update(s) skipped (step 3: non-finite learning rate (Config.lr_init, lr_final, ' \
         'lr_delay_mult), then new parameters / optimizer state); 2 in all' in out
  assert 'steps 5-6: 1 update(s) skipped (step 6: ' in out and 'steps 7-8' not in out and 'step 4:' not in out
  assert 'Trained to step 8' in out and '3 update(s) were skipped for non-finite values' in out
  assert _saved_steps(run) == [4, 8]


def test_raise_policy_stops_at_the_offending_step_before_saving_it(tmp_path, scene_dir, monkeypatch):
  _nan_data_at(monkeypatch, [3])
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 6', 'Config.checkpoint_every = 1',
                       "Config.nonfinite_grad_policy = 'raise'")
  with pytest.raises(train_step.NonFiniteError, match=r'^step 3: non-finite targets of the batch \(colours of the '
                     r'images, depth priors\), then loss, gradients, new parameters'):
    loop.train(config)
  assert _saved_steps(tmp_path / 'run') == [1, 2]


def test_max_skipped_steps_in_a_row_stop_the_run(tmp_path, scene_dir, monkeypatch):
  _nan_lr_at(monkeypatch, list(range(3, 40)))
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 40', 'Config.checkpoint_every = 1',
                       'Config.print_every = 2', 'Config.max_skipped_steps = 4')
  with pytest.raises(train_step.NonFiniteError, match=r'^steps 3-6: 4 consecutive updates skipped \(last: '
                     r'non-finite learning rate \(Config.lr_init, .*Config.max_skipped_steps = 4'):
    loop.train(config)
  assert _saved_steps(tmp_path / 'run') == [1, 2, 3, 4, 5]


def test_a_stop_names_the_first_non_finite_quantity_and_the_setting_that_made_it(tmp_path, scene_dir, monkeypatch):
  monkeypatch.setattr(occlusion, 'occlusion_loss', lambda *args: jnp.float32(10.))  # x 1e38: beyond float32.
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 4', 'Config.max_skipped_steps = 2',
                       'Config.occ_reg_loss_mult = 1e38')
  with pytest.raises(train_step.NonFiniteError, match=r'^steps 1-2: 2 consecutive updates skipped \(last: non-finite '
                     r'loss_occ x its weight Config.occ_reg_loss_mult, then loss\), Config.max_skipped_steps = 2;'):
    loop.train(config)


@pytest.mark.parametrize('translation, message', [
    ('1e400', 'Config.camera_noise_translation = inf; expected a finite number'),
    ('1e39', 'Config.camera_noise_translation = 1e+39; expected a finite number float32 holds (|x| <= 3.403e+38)'),
    ('1e38', "Config.camera_noise_translation = 1e+38 moves the training cameras by 4e+38 (x the camera distance 4), "
             "beyond float32's range")])
def test_noise_on_the_cameras_beyond_float32_is_refused_before_training(tmp_path, scene_dir, capsys, translation,
                                                                          message):
  bindings = TINY + [f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'",
                     f'Config.camera_noise_translation = {translation}', 'Config.max_skipped_steps = 2',
                     'Config.max_steps = 4']
  assert cli.run(lambda: train.main(['--gin_configs', DEMO, '--gin_bindings', *bindings])) == cli.USAGE_ERROR_STATUS
  err = capsys.readouterr().err
  assert err.splitlines()[-1].startswith(f'error: {message}') and err.count('error') == 1, err
  assert not list((tmp_path / 'run').glob('checkpoints/*'))


def test_a_state_with_nan_is_never_saved(tmp_path):
  state = train_step.TrainState(step=jnp.array(3), params={'a': jnp.ones(2), 'b': jnp.array([0., np.inf])},
                                opt_state=())
  mngr = checkpoints.manager(str(tmp_path), 2)
  with pytest.raises(train_step.NonFiniteError, match=r"^step 3: refusing to save .* \.params\['b'\]"):
    checkpoints.save(mngr, state)
  mngr.close()
  assert jax.tree.leaves(state) and not list(tmp_path.glob('checkpoints/3*'))


def test_max_skipped_steps_must_be_positive():
  with pytest.raises(ValueError, match=r'Config.max_skipped_steps = 0; expected a positive integer'):
    config_loader.validate(configs.Config(max_skipped_steps=0))
