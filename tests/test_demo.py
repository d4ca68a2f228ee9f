"""The demo: both methods share every setting but the regularizers, the side-by-side picture, the whole command."""

import dataclasses
import os

import gin

import numpy as np
from PIL import Image
import pytest

from internal import config_loader
from internal import demo
from internal.evaluation import evaluate
from internal.training import loop
from test_checkpoints import TINY
import train

REGULARIZERS = {'freq_reg', 'freq_reg_end', 'occ_reg_loss_mult'}
# The pipeline check: the demo's model, samples, batching, schedule and step count on every training view without
# regularizers (mip-NeRF). At the demo's 64 x 80 pixels it measured 25.56 dB test PSNR over the 8 test views; the
# test reduces only the evaluation (no LPIPS).
PIPELINE = ['Config.n_input_views = 0', 'Config.compute_lpips = False']
PIPELINE_MIN_PSNR = 25.


def test_the_two_demo_configs_differ_only_in_name_run_and_regularizers():
  cfgs = demo.method_configs()
  free, mip = dataclasses.asdict(cfgs['FreeNeRF']), dataclasses.asdict(cfgs['mip-NeRF'])
  assert {k for k in free if free[k] != mip[k]} == {'expname', 'checkpoint_dir'} | REGULARIZERS
  assert (mip['freq_reg'], mip['freq_reg_end'], mip['occ_reg_loss_mult']) == (False, 0, 0.)
  assert free['freq_reg'] and free['freq_reg_end'] == free['max_steps'] // 2 and free['occ_reg_loss_mult'] > 0
  assert os.path.dirname(free['checkpoint_dir']) == os.path.dirname(mip['checkpoint_dir']) == 'out/demo'


def test_one_run_directory_for_both_methods_is_refused():
  with pytest.raises(ValueError, match="Config.checkpoint_dir = 'x' is bound for both"):
    demo.method_configs(["Config.checkpoint_dir = 'x'"])


def test_grid_places_upscaled_tiles_under_titles():
  tiles = [[np.full((2, 3, 3), .2 * (2 * r + c)) for c in range(2)] for r in range(3)]
  picture = demo.grid(tiles, ['a', 'b'], ['x', 'y', 'z'], title='t', scale=2)
  top0, th, tw = demo.HEADER + demo.LINE, 4, 6
  assert picture.shape == (top0 + 3 * (th + demo.GAP), demo.LABEL_WIDTH + 2 * (tw + demo.GAP), 3)
  assert picture.dtype == np.uint8
  for r in range(3):
    for c in range(2):
      top, left = top0 + r * (th + demo.GAP), demo.LABEL_WIDTH + c * (tw + demo.GAP)
      np.testing.assert_array_equal(picture[top:top + th, left:left + tw], int(.2 * (2 * r + c) * 255))
      assert (picture[top + th:top + th + demo.GAP, left:left + tw] == 255).all()   # White gap below.
  assert (picture[:demo.HEADER + demo.LINE] < 255).any()                            # Some title text drawn.
  assert demo.grid(tiles, ['a', 'b'], ['x', 'y', 'z']).shape[0] == picture.shape[0] - demo.LINE


def test_side_by_side_rows_columns_and_shared_depth_range():
  h, w = 2, 3
  truth = [np.full((h, w, 3), .1 * v) for v in range(3)]
  depths = [np.array([[2., 3., 4.], [5., 0., 6.]]) for _ in range(3)]
  renderings = {m: [{'rgb': np.full((h, w, 3), .5 + .1 * k), 'distance_mean': depths[v]} for v in range(3)]
                for k, m in enumerate(('mip-NeRF', 'FreeNeRF'))}
  tiles, columns, rows = demo.side_by_side(truth, renderings, depths, blocks_per_row=2)
  assert columns == ['ground truth', 'mip-NeRF', 'FreeNeRF'] * 2 and rows == ['colour', 'depth'] * 2
  assert len(tiles) == 4 and all(len(row) == 6 for row in tiles)
  np.testing.assert_array_equal(tiles[2][0], truth[2])                     # Third view: second block row.
  np.testing.assert_array_equal(tiles[0][4], renderings['mip-NeRF'][1]['rgb'])
  np.testing.assert_array_equal(tiles[2][3], 1.)                           # The padding block is blank.
  for depth_tile in tiles[1]:                                               # Identical depths, identical colours.
    np.testing.assert_array_equal(depth_tile, tiles[1][0])
  np.testing.assert_allclose(tiles[1][0][0, 0], demo.vis.colorize_depth(depths[0])[0, 0])


def test_curves_picture_needs_a_recorded_curve(tmp_path, monkeypatch):
  monkeypatch.chdir(tmp_path)
  cfgs = demo.method_configs()
  path = tmp_path / demo.CURVES
  assert not demo.write_curves(cfgs, str(path)) and not path.exists()
  os.makedirs(cfgs['FreeNeRF'].checkpoint_dir)
  (tmp_path / cfgs['FreeNeRF'].checkpoint_dir / 'learning_curve.csv').write_text('step,psnr,seconds\n50,12.5,3\n'
                                                                                 '100,14.,6\n')
  assert demo.write_curves(cfgs, str(path))
  with Image.open(path) as picture:
    assert picture.format == 'PNG' and picture.size == (640, 440)


def test_demo_command_writes_both_runs_picture_and_videos(tmp_path, monkeypatch, scene_dir):
  monkeypatch.chdir(tmp_path)
  bindings = TINY + [f"Config.data_dir = '{scene_dir}'", 'Config.max_steps = 4', 'Config.freq_reg_end = 3',
                     'Config.render_path_frames = 2', 'Config.compute_lpips = False', 'Config.eval_test_ids = [0, 1]']
  assert train.main(['--gin_bindings', *bindings]) == 0
  cfgs = demo.method_configs(bindings)
  for name, run in (('FreeNeRF', 'freenerf'), ('mip-NeRF', 'mipnerf')):
    assert cfgs[name].checkpoint_dir == f'out/demo/{run}'
    record = evaluate.existing_record(cfgs[name])
    assert record['step'] == 4 and record['method'] == run
    gin_text = (tmp_path / 'out' / 'demo' / run / 'config.gin').read_text()
    assert f"Config.expname = '{run}'" in gin_text and f'freq_reg = {run == "freenerf"}' in gin_text
    renders = tmp_path / 'out' / 'demo' / run / 'path_renders_step_4'
    assert (renders / f'generated_object_{run}_color.mp4').stat().st_size > 0
  picture = np.asarray(Image.open(tmp_path / 'out' / 'demo' / demo.PICTURE))
  views = len(demo.SHOWN_VIEWS) // demo.BLOCKS_PER_ROW
  assert picture.shape == (demo.HEADER + demo.LINE + 2 * views * (32 * demo.SCALE + demo.GAP),
                           demo.LABEL_WIDTH + 3 * demo.BLOCKS_PER_ROW * (40 * demo.SCALE + demo.GAP), 3)
  assert (tmp_path / 'out' / 'demo' / demo.ORBIT_VIDEO).stat().st_size > 0
  with Image.open(tmp_path / 'out' / 'demo' / demo.CURVES) as curves:   # One point each: the last step.
    assert curves.format == 'PNG' and curves.size == (640, 440)
  assert train.main(['--gin_bindings', *bindings]) == 0   # Again: everything is done, nothing is refused.


def test_demo_settings_reconstruct_the_scene_from_all_views(tmp_path):
  gin.clear_config()
  config = config_loader.load_config(demo.METHODS['mip-NeRF'], PIPELINE + [
      f"Config.data_dir = '{tmp_path / 'scene'}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'"])
  assert config.n_input_views == 0 and not config.freq_reg and config.lr_final == demo.method_configs()[
      'FreeNeRF'].lr_final
  loop.train(config)
  record = evaluate.evaluate(config)
  assert record['complete'] and record['means']['psnr'] >= PIPELINE_MIN_PSNR, record['means']
