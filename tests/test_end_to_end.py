"""End to end on the generated scene: train a tiny model, evaluate, render; outputs, metrics and refusals."""

import csv
import dataclasses
import json
import os

import jax
import matplotlib
import numpy as np
from PIL import Image
import pytest
from jax import random

from conftest import SHARED_DATA
from internal import datasets
from internal import runs
from internal.evaluation import evaluate
from internal.evaluation import inference
from internal.evaluation import metrics
from internal.evaluation import render_path
from internal.evaluation import results
from internal.training import train_step
from internal.pipeline import loop
from internal.evaluation import vis
from test_checkpoints import ROOT, tiny_config

STEPS = 300


def _untrained_psnr(config, test_set) -> float:
  """Mean test PSNR of the freshly initialized model (what training must beat)."""
  model, state = train_step.create_train_state(config, random.PRNGKey(config.jax_rng_seed),
                                               jax.tree.map(lambda x: x[0, 0, :8], test_set.rays))
  render_fn = inference.make_render_fn(config, model, state.params, 0)
  return float(np.mean([metrics.psnr(inference.render_image(
      render_fn, jax.tree.map(lambda x, i=i: x[i], test_set.rays), config.render_chunk_size)['rgb'],
      test_set.images[i]) for i in range(len(test_set.ids))]))


def _config(run, scene, *bindings):
  """The e2e config (re-parsed: every test starts with gin cleared): a tiny FreeNeRF on 9 generated views."""
  return tiny_config(scene, run, f'Config.max_steps = {STEPS}', 'Config.n_input_views = 9', 'MLP.net_depth = 4',
                     'MLP.net_width = 64', 'Config.batch_size = 256', f'Config.freq_reg_end = {STEPS // 2}',
                     f'Config.train_render_every = {STEPS}', 'Config.render_path_frames = 3',
                     f"Config.lpips_weights_path = '{run}/no_such.pkl'", *bindings)


@pytest.fixture(scope='module')
def trained(tmp_path_factory, scene_dir):  # pylint: disable=redefined-outer-name
  """(run dir, scene dir) of the e2e config trained for STEPS steps."""
  run = tmp_path_factory.mktemp('e2e') / 'run'
  loop.train(_config(run, scene_dir))
  return run, scene_dir


def test_training_beats_the_untrained_model_and_eval_writes_everything(trained):
  run, _ = trained
  config = _config(*trained)
  record = evaluate.evaluate(config)
  out_dir = evaluate.output_dir(str(run), STEPS)
  test_set = datasets.load_dataset('test', config)
  assert record['step'] == STEPS and record['complete'] and len(record['per_image']) == len(test_set.ids)
  assert record['means']['psnr'] > _untrained_psnr(config, test_set) + 3.
  assert results.read_record(os.path.join(out_dir, results.METRICS_FILENAME)) == json.loads(json.dumps(record))
  assert record['means']['lpips'] is None and 'no_such.pkl' in record['lpips_missing_reason']
  with open(os.path.join(out_dir, 'metrics.csv')) as f:
    rows = list(csv.DictReader(f))
  assert [int(r['id']) for r in rows] == list(test_set.ids) and rows[0]['lpips'] == ''
  np.testing.assert_allclose([float(r['psnr']) for r in rows], [p['psnr'] for p in record['per_image']])
  for view_id in test_set.ids:
    for name in ('color', 'depth', 'opacity'):
      assert os.path.isfile(os.path.join(out_dir, f'{name}_{view_id:03d}.png'))
  assert os.listdir(run / 'tensorboard') and (run / 'config.gin').is_file()


def test_eval_never_replaces_a_finished_evaluation(trained):
  config = _config(*trained)
  if evaluate.existing_record(config) is None:
    evaluate.evaluate(config)
  with pytest.raises(FileExistsError, match='Config.overwrite'):
    evaluate.evaluate(config)


def test_eval_subset_at_lower_resolution_is_marked_incomplete(trained):
  config = _config(*trained, 'Config.eval_test_ids = [1, 3]', 'Config.eval_factor = 2',
                   'Config.compute_lpips = False', 'Config.overwrite = True')
  record = evaluate.evaluate(config)
  assert not record['complete'] and [p['id'] for p in record['per_image']] == [1, 3]
  assert record['lpips_missing_reason'] == 'Config.compute_lpips = False'
  image = np.asarray(Image.open(os.path.join(evaluate.output_dir(config.checkpoint_dir, STEPS),
                                                          'color_001.png')))
  assert image.shape == (16, 20, 3)
  with pytest.raises(ValueError, match='Config.eval_test_ids'):
    evaluate.select_positions(dataclasses.replace(config, eval_test_ids=[99]), 8)


def test_render_writes_the_frames_and_refuses_to_replace_them(trained):
  config = _config(*trained)
  out_dir = render_path.render(config)
  assert out_dir == render_path.output_dir(config.checkpoint_dir, STEPS)
  for f in range(3):
    for name in ('color', 'depth', 'opacity'):
      assert os.path.isfile(os.path.join(out_dir, f'{name}_{f:03d}.png'))
  with pytest.raises(FileExistsError, match='Config.overwrite'):
    render_path.render(config)


def test_dtu_eval_reports_full_and_object_metrics(tmp_path):
  scan = SHARED_DATA / 'dtu' / 'dtu_scan24'
  if not scan.is_dir():
    pytest.skip(f'no DTU scan under {scan}')
  config = runs.bind_fresh([str(ROOT / 'configs' / 'freenerf' / 'dtu3_freenerf.gin')], [
      f"Config.data_dir = '{scan.parent}'", "Config.dtu_scan = 'dtu_scan24'", "Config.dtu_mask_path = ''",
      'Config.allow_missing_test_views = True', 'Config.factor = 16', 'Config.max_steps = 2',
      f"Config.checkpoint_dir = '{tmp_path / 'run'}'", 'Config.batch_size = 64', 'Config.eval_test_ids = [0, 1]',
      'Config.compute_lpips = False', 'MLP.net_depth = 2', 'MLP.net_width = 16', 'MipNerfModel.num_samples = 8'])
  loop.train(config)
  record = evaluate.evaluate(config)
  assert (record['dataset'], record['scene'], record['n_input_views']) == ('dtu', 'dtu_scan24', 3)
  assert not record['complete'] and [p['id'] for p in record['per_image']] == [1, 9]
  for name in metrics.FULL_METRICS + metrics.MASKED_METRICS:
    assert name in record['means']
  assert np.isfinite(record['means']['psnr_masked']) and np.isfinite(record['means']['ssim_masked'])
  assert record['means']['psnr_masked'] != record['means']['psnr']


def test_nonfinite_gradients_raise_under_the_raise_policy(tmp_path, scene_dir):  # pylint: disable=redefined-outer-name
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 3',
                       "Config.nonfinite_grad_policy = 'raise'")
  with pytest.raises(train_step.NonFiniteError, match='^step 1: non-finite learning rate'):
    loop.train(dataclasses.replace(config, lr_init=float('nan')))  # Caught at step 1, before any update.


def test_png_truncates_as_released_and_depth_is_turbo_near_red(tmp_path):
  path = str(tmp_path / 'x.png')
  vis.save_png(np.array([[[0.999, 1.5, np.nan], [-0.2, 0.5, 1.]]]), path)
  np.testing.assert_array_equal(np.asarray(Image.open(path)), [[[254, 255, 0], [0, 127, 255]]])
  depth = np.linspace(1., 4., 200).reshape(10, 20)
  lo, hi = vis.depth_range(depth)
  np.testing.assert_allclose([lo, hi], np.percentile(-np.log(depth), [0.5, 99.5]))
  colours = vis.colorize_depth(depth)
  turbo = matplotlib.colormaps['turbo']
  np.testing.assert_allclose(colours[0, 0], turbo(1.)[:3])   # Nearest: top of the map (red).
  np.testing.assert_allclose(colours[-1, -1], turbo(0.)[:3])  # Farthest: bottom of the map (blue).
