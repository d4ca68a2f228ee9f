"""The demo: FreeNeRF and its NeRF baseline, trained alike on 2 views of the generated scene, side by side.

Each method is one run directory; FreeNeRF is configs/demo.gin (the short schedule) then configs/demo_forward.gin
(the scene, its 2 views and the small NeRF), the baseline adds configs/demo_nerf.gin, which only names its run and
switches the regularizers off. After both are trained, evaluated and rendered, `finish` writes to the runs'
parent folder demo.png (per shown test view a colour and a depth row: ground truth | NeRF | FreeNeRF),
demo_curves.png (both runs' learning curves: test PSNR against the step) and demo_orbit.mp4 (both orbits side by
side, when imageio-ffmpeg is installed).
"""

import os

import numpy as np
from PIL import Image

from internal.run import checkpoints
from internal import datasets
from internal.evaluation import depth_metrics
from internal.evaluation import evaluate
from internal.evaluation import learning_curve
from internal.evaluation import render_path
from internal.evaluation import vis
from internal import cli
from internal import runs
from internal.run import run_dir

METHODS = {'NeRF': cli.DEMO_CONFIGS + [os.path.join(cli.CONFIG_DIR, 'demo_nerf.gin')],
           'FreeNeRF': cli.DEMO_CONFIGS}
MAX_SHOWN_VIEWS = 4            # Test views in the picture, evenly spread over the evaluated ones.
BLOCKS_PER_ROW = 2             # Test views side by side in the picture.
SCALE = 2                      # Nearest-neighbour upscaling of the small renders.
PICTURE, CURVES, ORBIT_VIDEO = 'demo.png', 'demo_curves.png', 'demo_orbit.mp4'


def method_config(name: str, bindings=()):
  """`with method_config(name, bindings) as config:` one method's validated Config, gin holding its settings (which
  its model reads) until the block ends (runs.fresh_config)."""
  return runs.fresh_config(METHODS[name], bindings)


def method_configs(bindings=()) -> dict:
  """{method name: validated Config} of both demo configs with the same extra bindings applied to each; gin is
  cleared after each, so what reads the model's settings from gin (training, a run directory's check) takes its
  Config from method_config instead."""
  out = {}
  for name in METHODS:
    with method_config(name, bindings) as config:
      out[name] = config
  dirs = [c.checkpoint_dir for c in out.values()]
  if len(set(map(os.path.abspath, dirs))) != len(dirs):
    raise ValueError(f'the demo needs one run directory per method, but Config.checkpoint_dir = {dirs[0]!r} is '
                     'bound for both; leave Config.checkpoint_dir to configs/demo*.gin')
  return out


def output_dir(method_cfgs: dict) -> str:
  """The folder of the demo's picture and video: the parent of the FreeNeRF run directory."""
  return os.path.dirname(os.path.abspath(method_cfgs['FreeNeRF'].checkpoint_dir))


def evaluate_and_render(config) -> dict:
  """Evaluates and renders the orbit of a trained run, each unless done for its newest step; metrics record."""
  record = evaluate.existing_record(config) or evaluate.evaluate(config)
  if not render_path.existing_renders(config):
    render_path.render(config)
  return record


def shown_positions(num_views: int, max_shown: int = MAX_SHOWN_VIEWS) -> list:
  """Indices of the num_views evaluated test views shown in the picture: every k-th, at most max_shown of them."""
  return list(range(0, num_views, -(-num_views // max_shown)))


def evaluated_views(config, record: dict, test_set, positions) -> list:
  """Renderings {'rgb', 'distance_mean'} [H, W, ...] at test positions, read back from the run's evaluation.

  rgb is evaluation's colour PNG; distance_mean the world ray parameter of its raw depth file (converted back from
  NDC for the forward rig), as the ground-truth depths, so that both share one colour scale.
  """
  eval_dir = evaluate.output_dir(run_dir.outputs_root(config), record['step'])
  ndc = bool(datasets.loader.ndc(config))
  out = []
  for i in positions:
    view_id = int(test_set.ids[i])
    with Image.open(os.path.join(eval_dir, f'color_{view_id:03d}.png')) as image:
      rgb = np.asarray(image.convert('RGB'), np.float32) / 255.
    with np.load(depth_metrics.depth_file(eval_dir, view_id)) as depth:
      out.append({'rgb': rgb, 'distance_mean': depth_metrics.world_depth(test_set, i, depth['distance'], ndc)})
  return out


def side_by_side(truth: list, renderings: dict, truth_depths: list, blocks_per_row: int = BLOCKS_PER_ROW) -> tuple:
  """(tiles, column titles, row titles): per view a colour row and a depth row, ground truth then each method.

  truth: images [h, w, 3] per view; renderings: {method: per-view renderings}; truth_depths: [h, w] per view
  (0 where nothing is hit). Each view's depths share the ground truth's colour range. Views are laid out in
  blocks of columns, blocks_per_row to a row.
  """
  blocks = []
  for v, image in enumerate(truth):
    depth_range = vis.depth_range(truth_depths[v])
    colour = [image] + [np.asarray(r[v]['rgb']) for r in renderings.values()]
    depth = [vis.colorize_depth(truth_depths[v], depth_range)] + [
        vis.colorize_depth(r[v]['distance_mean'], depth_range) for r in renderings.values()]
    blocks.append([colour, depth])
  blank = [[np.ones_like(tile) for tile in row] for row in blocks[0]]
  blocks += [blank] * (-len(blocks) % blocks_per_row)
  tiles = [sum((blocks[b + k][r] for k in range(blocks_per_row)), [])
           for b in range(0, len(blocks), blocks_per_row) for r in range(2)]
  columns = (['ground truth'] + list(renderings)) * blocks_per_row
  return tiles, columns, ['colour', 'depth'] * (len(blocks) // blocks_per_row)


def write_picture(truth, records: dict, renderings: dict, n_input_views: int, path: str) -> np.ndarray:
  """Writes the side-by-side picture of the shown views to path; returns it.

  truth: (images, depths) of the shown test views; records: {method: metrics record}; renderings: {method:
  renderings of the shown views}.
  """
  tiles, columns, rows = side_by_side(truth[0], renderings, truth[1])
  scores = ', '.join(f'{name} {record["means"]["psnr"]:.2f} dB' for name, record in records.items())
  evaluated = len(records['FreeNeRF']['per_image'])
  title = f'{n_input_views} training views; test PSNR over {evaluated} views: {scores}'
  picture = vis.grid(tiles, columns, rows, title, scale=SCALE)
  vis.save_picture(picture, path)
  return picture


def write_curves(method_cfgs: dict, path: str) -> bool:
  """Writes the runs' learning curves (test PSNR against the step) as a PNG; False when none was recorded."""
  lines = {name: [(row['step'], row['psnr']) for row in learning_curve.read_rows(
      learning_curve.csv_path(cfg.checkpoint_dir))] for name, cfg in method_cfgs.items()}
  lines = {name: points for name, points in lines.items() if points}
  if not lines:
    return False
  config = method_cfgs['FreeNeRF']
  fig, ax = vis.line_figure(lines)
  vis.save_figure(fig, ax, 'training step', 'test PSNR (dB)', f'{config.n_input_views} training views; test '
                  f'positions {list(config.curve_test_ids)} at 1/{config.curve_factor} size', path)
  return True


def write_orbit_video(method_cfgs: dict, path: str) -> bool:
  """Writes both methods' orbit renders side by side (colour row, depth row) as an mp4; False without ffmpeg."""
  if not render_path.can_write_video():
    return False
  folders = {name: render_path.output_dir(run_dir.outputs_root(cfg), checkpoints.latest_step(cfg.checkpoint_dir))
             for name, cfg in method_cfgs.items()}
  num_frames = next(iter(method_cfgs.values())).render_path_frames

  def frame(f):
    tiles = [[np.asarray(Image.open(os.path.join(d, f'{kind}_{f:03d}.png'))) / 255. for d in folders.values()]
             for kind in ('color', 'depth')]
    picture = vis.grid(tiles, list(folders), ['colour', 'depth'], scale=SCALE)
    return picture[:picture.shape[0] // 2 * 2, :picture.shape[1] // 2 * 2]  # Even sizes for h264.
  render_path.write_video(np.stack([frame(f) for f in range(num_frames)]), path)
  return True


def finish(bindings=()) -> dict:
  """Evaluates and renders both trained runs, writes the picture and the orbit video; {method: test PSNR}."""
  method_cfgs, records, renderings = {}, {}, {}
  for name in METHODS:
    with method_config(name, bindings) as config:
      method_cfgs[name] = config
      records[name] = record = evaluate_and_render(config)
      test_set = datasets.load_dataset('test', config, ground_truth=True)
      evaluated = record['test_positions']
      positions = [evaluated[k] for k in shown_positions(len(evaluated))]
      renderings[name] = evaluated_views(config, record, test_set, positions)
  out_dir = output_dir(method_cfgs)
  truth = [test_set.images[p] for p in positions], [test_set.depths[p] for p in positions]
  write_picture(truth, records, renderings, config.n_input_views, os.path.join(out_dir, PICTURE))
  write_curves(method_cfgs, os.path.join(out_dir, CURVES))
  if not write_orbit_video(method_cfgs, os.path.join(out_dir, ORBIT_VIDEO)):
    print(render_path.VIDEO_HINT)
  return {name: record['means']['psnr'] for name, record in records.items()}
