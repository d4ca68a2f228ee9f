"""The demo: both methods share every setting but the regularizers, the side-by-side picture, the whole command."""

import dataclasses
import json
import os
import pathlib
import statistics


import numpy as np
from PIL import Image
import pytest

from internal import cli
from internal import demo
from internal import runs
from internal.evaluation import evaluate
from internal.evaluation import vis
from internal.pipeline import loop
from test_checkpoints import TINY
from lab import demo_seeds
from tools import provenance
import train

REGULARIZERS = {'freq_reg', 'freq_reg_end', 'freq_reg_end_fraction', 'occ_reg_loss_mult'}
# The demo's results, per seed, as `python -m lab.demo_seeds` recorded them (results/demo/README.md). The tests below
# train with the default seed and compare with what was recorded for it (what the demo shows: results/README.md).
RESULTS = pathlib.Path(__file__).resolve().parents[1] / 'results' / 'demo'
# On the machine and versions that recorded them a run reproduces them; within this of them, in dB.
REPRODUCED = .01
# The pipeline check: the demo's model, samples, batching, schedule, step count and scene on every training view
# (all 17) without regularizers (NeRF); the test reduces only the evaluation (no LPIPS).
PIPELINE = ['Config.n_input_views = 0', 'Config.compute_lpips = False']


def recorded() -> list:
  """The per-seed records of results/demo of this machine's kind (the CPU's instruction set), by seed;
  where this kind has none, those of every kind."""
  here = demo_seeds.kind_dir(str(RESULTS))
  if os.path.isdir(here):
    return demo_seeds.read_seeds(here)
  return [r for kind in sorted(os.listdir(RESULTS)) if os.path.isdir(RESULTS / kind)
          for r in demo_seeds.read_seeds(str(RESULTS / kind))]


def accepted_range(values: list, reproduced: bool) -> tuple:
  """(low, high) a run of the default seed (values[0]) must fall in: within REPRODUCED of it where the recording
  machine and versions are this one's; elsewhere a different rounding takes another trajectory, as another seed
  does: the range of the recorded seeds widened by their sample standard deviation on each side.

  With the 3 seeds recorded: all views 25.97 (21.78 to 25.97 over the seeds, std 2.26: 19.52 to 28.23 elsewhere),
  FreeNeRF from 2 views 21.94 (19.32 to 21.94, std 1.46: 17.86 to 23.40 elsewhere). Where they were recorded a
  regression of 0.01 dB fails; elsewhere the seeds' chaos hides any change that stays within their spread.
  """
  if reproduced:
    return values[0] - REPRODUCED, values[0] + REPRODUCED
  spread = statistics.stdev(values)
  return min(values) - spread, max(values) + spread


def same_machine(record: dict) -> bool:
  """Whether this machine and its versions compute as those that recorded a result: the machine kind
  (environment.cpu_isa), the cores (XLA's threads), jax and Python; not the CPU's name (one name spans several
  kinds)."""
  here = provenance.record([])['machine']
  return all(record['provenance']['machine'].get(key) == here[key] for key in ('isa', 'cpu_count', 'jax', 'python'))


def check_against_recorded(psnr: float, key) -> None:
  """Asserts a default-seed PSNR falls in the accepted range of the recorded seeds' key(record)."""
  records = sorted(recorded(), key=lambda r: r['seed'] != demo_seeds.DEFAULT_SEED)
  low, high = accepted_range([key(r) for r in records], same_machine(records[0]))
  assert low <= psnr <= high, (f'{psnr:.2f} dB is outside [{low:.2f}, {high:.2f}] of results/demo (per seed '
                               f'{[round(key(r), 2) for r in records]}); if the demo changed on purpose, record it '
                               'again: python -m lab.demo_seeds --seeds ' + ' '.join(str(r['seed']) for r in records)
                               + ' (a folder per machine kind: results/demo/README.md)')


def test_shown_positions_spread_over_the_test_split():
  assert demo.shown_positions(8) == [0, 2, 4, 6]     # The object rig's test orbit, every 90 degrees.
  assert demo.shown_positions(3) == [0, 1, 2]        # The forward rig's 3 test views.
  assert demo.shown_positions(24) == [0, 6, 12, 18] and demo.shown_positions(1) == [0]


def test_the_two_demo_configs_differ_only_in_name_run_and_regularizers():
  cfgs = demo.method_configs()
  free, base = dataclasses.asdict(cfgs['FreeNeRF']), dataclasses.asdict(cfgs['NeRF'])
  assert {k for k in free if free[k] != base[k]} == {'expname', 'checkpoint_dir'} | REGULARIZERS
  assert (base['freq_reg'], base['freq_reg_end'], base['freq_reg_end_fraction'], base['occ_reg_loss_mult']) == (
      False, 0, 0., 0.)
  assert free['freq_reg'] and free['freq_reg_end'] == free['max_steps'] * 9 // 10 and free['occ_reg_loss_mult'] > 0
  assert (free['model'], free['freq_mask_layout']) == ('nerf', 'paper')
  assert (free['generated_rig'], free['n_input_views'], free['near'], free['far']) == ('forward', 2, 0., 1.)
  assert os.path.dirname(free['checkpoint_dir']) == os.path.dirname(base['checkpoint_dir']) == 'out/demo'


def test_one_run_directory_for_both_methods_is_refused():
  with pytest.raises(ValueError, match="Config.checkpoint_dir = 'x' is bound for both"):
    demo.method_configs(["Config.checkpoint_dir = 'x'"])


def test_grid_places_upscaled_tiles_under_titles():
  tiles = [[np.full((2, 3, 3), .2 * (2 * r + c)) for c in range(2)] for r in range(3)]
  picture = vis.grid(tiles, ['a', 'b'], ['x', 'y', 'z'], title='t', scale=2)
  top0, th, tw = vis.HEADER + vis.LINE, 4, 6
  assert picture.shape == (top0 + 3 * (th + vis.GAP), vis.LABEL_WIDTH + 2 * (tw + vis.GAP), 3)
  assert picture.dtype == np.uint8
  for r in range(3):
    for c in range(2):
      top, left = top0 + r * (th + vis.GAP), vis.LABEL_WIDTH + c * (tw + vis.GAP)
      np.testing.assert_array_equal(picture[top:top + th, left:left + tw], int(.2 * (2 * r + c) * 255))
      assert (picture[top + th:top + th + vis.GAP, left:left + tw] == 255).all()   # White gap below.
  assert (picture[:vis.HEADER + vis.LINE] < 255).any()                            # Some title text drawn.
  assert vis.grid(tiles, ['a', 'b'], ['x', 'y', 'z'], scale=2).shape[0] == picture.shape[0] - vis.LINE


def test_a_long_row_title_widens_its_column_instead_of_covering_the_tiles():
  tiles = [[np.zeros((8, 8, 3))]]
  picture = vis.grid(tiles, ['a'], ['test view 100 of many'], scale=1)
  left0 = vis.label_width(['test view 100 of many'])
  assert left0 > vis.LABEL_WIDTH and picture.shape[1] == left0 + 8 + vis.GAP
  assert (picture[vis.HEADER:vis.HEADER + 8, left0:left0 + 8] == 0).all()        # The tile, untouched by text.
  assert (picture[vis.HEADER:vis.HEADER + 8, vis.LABEL_WIDTH:left0] < 255).any()  # The title's end, beside it.


def test_long_column_titles_wrap_to_their_tiles_width_and_push_the_tiles_down():
  tiles = [[np.zeros((8, 120, 3)), np.zeros((8, 120, 3))]]
  long = 'freenerf_refine noise=exact seed=0 a_label_wider_than_its_tile'
  font = vis.label_font()
  lines = vis.wrap_label(long, 118, font)
  assert lines == ['freenerf_refine', 'noise=exact seed=0', 'a_label_wider_than_its_tile']
  assert all(font.getlength(t) <= 118 for t in lines[:2])
  picture = vis.grid(tiles, [long, 'b'], ['x'], scale=1)
  top0 = vis.HEADER + 2 * vis.LINE  # Two extra lines for the three of the longest title.
  assert picture.shape[0] == top0 + 8 + vis.GAP
  assert (picture[top0:top0 + 8, vis.LABEL_WIDTH:vis.LABEL_WIDTH + 120] == 0).all()  # The tile, under no text.
  assert (picture[:top0 - vis.LINE, vis.LABEL_WIDTH + 120:vis.LABEL_WIDTH + 120 + vis.GAP] == 255).all()


def test_side_by_side_rows_columns_and_shared_depth_range():
  h, w = 2, 3
  truth = [np.full((h, w, 3), .1 * v) for v in range(3)]
  depths = [np.array([[2., 3., 4.], [5., 0., 6.]]) for _ in range(3)]
  renderings = {m: [{'rgb': np.full((h, w, 3), .5 + .1 * k), 'distance_mean': depths[v]} for v in range(3)]
                for k, m in enumerate(('NeRF', 'FreeNeRF'))}
  tiles, columns, rows = demo.side_by_side(truth, renderings, depths, blocks_per_row=2)
  assert columns == ['ground truth', 'NeRF', 'FreeNeRF'] * 2 and rows == ['colour', 'depth'] * 2
  assert len(tiles) == 4 and all(len(row) == 6 for row in tiles)
  np.testing.assert_array_equal(tiles[2][0], truth[2])                     # Third view: second block row.
  np.testing.assert_array_equal(tiles[0][4], renderings['NeRF'][1]['rgb'])
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


@pytest.mark.slow
def test_demo_command_writes_both_runs_picture_and_videos(tmp_path, monkeypatch):
  monkeypatch.chdir(tmp_path)
  bindings = TINY + [f"Config.data_dir = '{tmp_path / 'forward_scene'}'", 'Config.max_steps = 4', 'Config.freq_reg_end = 3',
                     'Config.render_path_frames = 2', 'Config.compute_lpips = False', 'Config.eval_test_ids = [0, 1]']
  assert train.main(['--gin_bindings', *bindings]) == 0
  for name, run in (('FreeNeRF', 'freenerf'), ('NeRF', 'nerf')):
    with demo.method_config(name, bindings) as config:  # The run's check reads the model's settings from gin.
      assert config.checkpoint_dir == f'out/demo/{run}'
      record = evaluate.existing_record(config)
    assert record['step'] == 4 and record['method'] == run
    gin_text = (tmp_path / 'out' / 'demo' / run / 'config.gin').read_text()
    assert f"Config.expname = '{run}'" in gin_text and f'freq_reg = {run == "freenerf"}' in gin_text
    renders = tmp_path / 'out' / 'demo' / run / 'path_renders_step_4'
    assert (renders / f'generated_forward_{run}_color.mp4').stat().st_size > 0
  picture = np.asarray(Image.open(tmp_path / 'out' / 'demo' / demo.PICTURE).convert('RGB'))  # Saved as a palette.
  block_rows = -(-len(demo.shown_positions(2)) // demo.BLOCKS_PER_ROW)  # The 2 evaluated test views.
  assert picture.shape == (vis.HEADER + vis.LINE + 2 * block_rows * (32 * demo.SCALE + vis.GAP),
                           vis.LABEL_WIDTH + 3 * demo.BLOCKS_PER_ROW * (40 * demo.SCALE + vis.GAP), 3)
  assert (tmp_path / 'out' / 'demo' / demo.ORBIT_VIDEO).stat().st_size > 0
  with Image.open(tmp_path / 'out' / 'demo' / demo.CURVES) as curves:   # One point each: the last step.
    assert curves.format == 'PNG' and curves.size == (640, 440)
  assert train.main(['--gin_bindings', *bindings]) == 0   # Again: everything is done, nothing is refused.


def test_the_accepted_range_is_the_recorded_run_here_and_the_seeds_spread_elsewhere():
  assert accepted_range([25.97, 22.40, 21.78], True) == pytest.approx((25.96, 25.98))
  spread = statistics.stdev([25.97, 22.40, 21.78])
  assert accepted_range([25.97, 22.40, 21.78], False) == pytest.approx((21.78 - spread, 25.97 + spread))
  record = {'provenance': provenance.record([])}
  assert same_machine(record)
  record['provenance']['machine']['cpu'] = 'another CPU'   # The same kind under another name computes alike.
  assert same_machine(record)
  record['provenance']['machine']['isa'] = 'SSE4_2'
  assert not same_machine(record)
  del record['provenance']['machine']['isa']               # A record that does not say its kind is another's.
  assert not same_machine(record)


@pytest.mark.parametrize('kind', sorted(k.name for k in RESULTS.iterdir() if k.is_dir()))
def test_the_recorded_results_are_the_demo_over_several_seeds(kind):
  records = demo_seeds.read_seeds(str(RESULTS / kind))
  seeds = [r['seed'] for r in records]
  assert len(seeds) >= 2 and demo_seeds.DEFAULT_SEED in seeds, seeds
  for record in records:  # Made by the demo's own commands, with no setting but the seed changed.
    assert record['demo']['command'] == cli.quoted(
        ['python', 'train.py'] + (['--gin_bindings', *demo_seeds.seed_bindings(record['seed'])]
                                  if record['seed'] != demo_seeds.DEFAULT_SEED else []))
    assert '+dirty' not in record['provenance']['commit'] and '--gin_bindings' not in record['provenance']['command']
    means = record['demo']['means']
    assert means['FreeNeRF']['psnr'] > means['NeRF']['psnr'], record['seed']  # FreeNeRF leads on every seed.
    assert record['provenance']['machine']['isa'] == kind
  assert json.loads((RESULTS / kind / demo_seeds.SUMMARY).read_text()) == json.loads(
      json.dumps(demo_seeds.summary(records)))
  assert (RESULTS / demo_seeds.README).read_text() == demo_seeds.index(str(RESULTS))


@pytest.mark.slow
def test_demo_settings_reconstruct_the_scene_from_all_views(tmp_path):
  freenerf_lr_final = demo.method_configs()['FreeNeRF'].lr_final  # Before binding: method_configs clears gin.
  config = runs.bind_fresh(demo.METHODS['NeRF'], PIPELINE + [
      f"Config.data_dir = '{tmp_path / 'scene'}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'"])
  assert config.n_input_views == 0 and not config.freq_reg and config.lr_final == freenerf_lr_final
  assert config.jax_rng_seed == demo_seeds.DEFAULT_SEED
  loop.train(config)
  record = evaluate.evaluate(config)
  assert record['complete']
  check_against_recorded(record['means']['psnr'], lambda r: r['all_views']['means']['psnr'])


@pytest.mark.slow
def test_demo_settings_freenerf_from_few_views_as_recorded(tmp_path):
  """FreeNeRF of the demo (2 views) trained as the demo does; the NeRF it leads is in the recorded results."""
  with demo.method_config('FreeNeRF', ['Config.compute_lpips = False', f"Config.data_dir = '{tmp_path / 'scene'}'",
                                        f"Config.checkpoint_dir = '{tmp_path / 'run'}'"]) as config:
    loop.train(config)
    record = evaluate.evaluate(config)
  assert record['complete'], record
  check_against_recorded(record['means']['psnr'], lambda r: r['demo']['means']['FreeNeRF']['psnr'])


def test_picture_labels_keep_their_spaces():
  font = vis.label_font()
  # PIL's default bitmap font draws a space 2 px wide ('mipnerfseed=0'); a real font's is a third of a letter's.
  assert font.getlength('a b') - font.getlength('ab') >= font.getlength('a') / 3
