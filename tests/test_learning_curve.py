"""Learning curves: rows against hand-computed PSNRs, the CSV across a resumed run, agreement with eval, errors."""

import csv
import dataclasses
import json
import os
import pathlib
import signal

import numpy as np
import pytest

from internal import config_loader
from internal import runs
from internal.evaluation import evaluate
from internal.evaluation import learning_curve
from internal.pipeline import loop
from internal.run import run_dir as run_dir_lib
from test_checkpoints import tiny_config

# Curve every 5 of 20 steps on test positions 1 and 3 at half the (32 x 40) size; the frequency mask is still
# opening at step 20 (T = 30), so a render with another step's masks would score differently.
CURVE = ('Config.curve_every = 5', 'Config.curve_test_ids = (1, 3)', 'Config.curve_factor = 2',
         'Config.max_steps = 20', 'Config.freq_reg_end = 30', 'Config.checkpoint_every = 10',
         'Config.compute_lpips = False')
MASK_STILL_OPENING = pytest.mark.filterwarnings('ignore:Config.freq_reg_end = 30 exceeds')


def test_row_by_hand():
  truth = np.zeros((2, 4, 6, 3))
  renders = [truth[0] + .1, truth[1] + .01]                       # 20 dB and 40 dB.
  row = learning_curve.curve_row(7, 12.5, truth, renders)
  assert row == {'step': 7, 'psnr': pytest.approx(30., abs=1e-9), 'seconds': 12.5}
  assert list(row) == ['step', 'psnr', 'seconds']


def test_masked_row_by_hand():
  truth = np.full((1, 4, 6, 3), .5)
  render = truth[0].copy()
  render[:2] += .1          # Rows 0-1: error 0.1, inside the mask.
  render[2:] += .5          # Rows 2-3: error 0.5, outside (mask 0, or 0.5 from a downsampled edge).
  mask = np.zeros((4, 6, 3))
  mask[:2] = 1.
  mask[2] = .5
  row = learning_curve.curve_row(3, 1., truth, [render], [mask])
  assert row['psnr'] == pytest.approx(-10. * np.log10((.01 + .25) / 2.), abs=1e-9)
  assert row['psnr_masked'] == pytest.approx(20., abs=1e-9)
  assert list(row) == ['step', 'psnr', 'psnr_masked', 'seconds']


def _csv_rows(path):
  with open(path, newline='') as f:
    return list(csv.DictReader(f))


@MASK_STILL_OPENING
def test_resumed_run_continues_the_csv_and_matches_eval(tmp_path, scene_dir):
  run = tmp_path / 'run'
  loop.train(tiny_config(scene_dir, run, *CURVE), stop_at_step=10)
  path = run / learning_curve.CSV_FILE
  assert [r['step'] for r in _csv_rows(path)] == ['5', '10']
  with open(path, 'a') as f:              # A row past the checkpoint: a crash after it, before the next save.
    f.write('15,99.0,1000.0,1.0\n')
  loop.train(tiny_config(scene_dir, run, *CURVE))
  rows = learning_curve.read_rows(str(path))
  assert [r['step'] for r in rows] == [5, 10, 15, 20]
  assert rows[2]['psnr'] != 99. and rows[2]['seconds'] < 1000.
  assert all(a['seconds'] < b['seconds'] for a, b in zip(rows, rows[1:]))
  assert all(8. < r['psnr'] < 40. for r in rows) and set(rows[0]) == {'step', 'psnr', 'seconds', 'compile_seconds'}
  # Each call compiled its step once: the resumed call's compilation adds to the first call's.
  assert 0 < rows[0]['compile_seconds'] == rows[1]['compile_seconds'] < rows[2]['compile_seconds'] < rows[2]['seconds']
  # The last point is what eval.py reports for the same views at the same size.
  config = tiny_config(scene_dir, run, *CURVE)
  record = evaluate.evaluate(dataclasses.replace(config, eval_test_ids=[1, 3], eval_factor=2))
  assert [entry['id'] for entry in record['per_image']] == learning_curve.load_views(
      config, evaluate.check_eval_inputs(config)).ids
  assert rows[-1]['psnr'] == pytest.approx(record['means']['psnr'], abs=1e-4)


@MASK_STILL_OPENING
@pytest.mark.parametrize('clock_step, continues_from_clock', [(12, True), (11, False)])
def test_a_resumed_run_counts_its_seconds_from_its_checkpoints_clock(tmp_path, scene_dir, clock_step,
                                                                    continues_from_clock):
  run = tmp_path / 'run'
  loop.train(tiny_config(scene_dir, run, *CURVE), stop_at_step=12)  # Rows 5 and 10, a checkpoint at step 12.
  clock = json.loads((run / learning_curve.CLOCK_FILE).read_text())
  rows = learning_curve.read_rows(str(run / learning_curve.CSV_FILE))
  assert clock['step'] == 12 and clock['seconds'] > rows[-1]['seconds'] and clock['compile_seconds'] > 0
  # Steps 11 and 12 took 1000 s and compiled for 100 s more: a clock of the checkpoint's step is taken, another
  # step's is not (then the seconds go on from the last row, as before clocks were kept).
  (run / learning_curve.CLOCK_FILE).write_text(json.dumps({'step': clock_step, 'seconds': 1000.,
                                                           'compile_seconds': 100.}))
  loop.train(tiny_config(scene_dir, run, *CURVE), stop_at_step=15)
  resumed = learning_curve.read_rows(str(run / learning_curve.CSV_FILE))[-1]
  assert resumed['step'] == 15 and (resumed['seconds'] > 1000.) == continues_from_clock
  assert (resumed['compile_seconds'] > 100.) == continues_from_clock


@MASK_STILL_OPENING
def test_a_run_stopped_at_a_curve_step_keeps_its_point(tmp_path, scene_dir, monkeypatch):
  make_batcher = loop.datasets.make_batcher

  def signalling(dataset, config):  # SIGTERM (a budget's end) while step 10, a curve step, is drawn.
    batcher = make_batcher(dataset, config)
    return lambda step: (os.kill(os.getpid(), signal.SIGTERM) if step == 10 else None) or batcher(step)
  monkeypatch.setattr(loop.datasets, 'make_batcher', signalling)
  run = tmp_path / 'run'
  assert loop.train(tiny_config(scene_dir, run, *CURVE)).signum == signal.SIGTERM
  monkeypatch.undo()
  loop.train(tiny_config(scene_dir, run, *CURVE))
  assert [r['step'] for r in learning_curve.read_rows(str(run / learning_curve.CSV_FILE))] == [5, 10, 15, 20]


def test_curve_settings_are_bookkeeping(tmp_path):
  first = run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path / 'run'))
  run_dir_lib.record_settings(first, tiny_config('s', tmp_path / 'run'))
  assert run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path / 'run', 'Config.curve_every = 3',
                                                 'Config.curve_test_ids = [5]', 'Config.curve_factor = 1')) == first


def test_a_damaged_csv_is_named(tmp_path):
  (tmp_path / learning_curve.CSV_FILE).write_text('step,psnr,seconds\nfive,1,2\n')
  with pytest.raises(ValueError, match=f"{learning_curve.CSV_FILE}' is not a learning curve"):
    learning_curve.CurveLog(str(tmp_path), 10)


@pytest.mark.parametrize('binding, message', [
    ('Config.curve_every = -1', 'Config.curve_every = -1; expected >= 0'),
    ('Config.curve_every = 2.5', 'Config.curve_every = 2.5; expected int'),
    ('Config.curve_factor = 0', 'Config.curve_factor = 0; expected a positive integer'),
    ('Config.curve_test_ids = []', r'Config.curve_test_ids = \[\]; expected a non-empty list'),
    ('Config.curve_test_ids = (0, 0)', r'Config.curve_test_ids = \(0, 0\); expected .* distinct'),
    ('Config.curve_test_ids = [-1]', r'Config.curve_test_ids = \[-1\]; expected'),
    ("Config.curve_test_ids = 'a'", "Config.curve_test_ids = 'a'; expected"),
    ('Config.curve_spread_views = -1', 'Config.curve_spread_views = -1; expected >= 0'),
])
def test_bad_settings_are_named(binding, message):
  with pytest.raises(ValueError, match=message):
    config_loader.load_config([], [binding])


@pytest.mark.parametrize('num_views, expected', [
    (13, [2, 6, 10]),   # Thirds [0, 4.33), [4.33, 8.67), [8.67, 13): middles 2.17, 6.5, 10.83.
    (25, [4, 12, 20]),  # Thirds of 25: middles 4.17, 12.5, 20.83.
    (3, [0, 1, 2])])
def test_spread_views_are_the_middle_of_equal_parts_of_the_test_split(num_views, expected):
  config = config_loader.load_config([], ['Config.curve_spread_views = 3', 'Config.curve_test_ids = (0, 1)'])
  assert learning_curve.curve_positions(config, num_views) == expected
  with pytest.raises(ValueError, match='Config.curve_spread_views = 3: the test split has only 2 views'):
    learning_curve.curve_positions(config, 2)


@pytest.mark.parametrize('name', ['freenerf/dtu3_freenerf.gin', 'mipnerf/dtu3_mipnerf.gin',
                                  'mini/dtu3_regnerf.gin'])
def test_dtu_configs_spread_their_curve_views(name):
  path = str(pathlib.Path(__file__).resolve().parents[1] / 'configs' / name)
  assert config_loader.load_config([path], ["Config.data_dir = 'elsewhere'"]).curve_spread_views == 3


def test_packed_scenes_need_the_packed_factor():
  with pytest.raises(ValueError, match='Config.curve_factor = 4: a packed scene .* set Config.curve_factor = 1'):
    config_loader.load_config([], ["Config.dataset_loader = 'packed'", 'Config.curve_every = 10'])
  runs.bind_fresh([], ["Config.dataset_loader = 'packed'", 'Config.curve_every = 0'])


@MASK_STILL_OPENING
def test_positions_beyond_the_test_split_stop_training_before_it_starts(tmp_path, scene_dir):
  config = tiny_config(scene_dir, tmp_path / 'run', *CURVE, 'Config.curve_test_ids = (1, 8)')
  with pytest.raises(ValueError, match=r'Config.curve_test_ids = \[1, 8\]: positions \[8\] are outside the 8 test'):
    loop.train(config)
  assert not (tmp_path / 'run' / 'checkpoints').exists()
