"""bench.gpu_report's picture: a labelled column per test view, the ground truth of those views (from the packed
scene the runs were evaluated on), then each run's colour and depth rows, every row labelled."""

import json

import numpy as np
from PIL import Image

from bench import gpu_report
from internal import demo
from internal.datasets import packed
from internal.evaluation import vis

H, W = 6, 8
IDS = [1, 9, 11]


def _flat(value: float) -> np.ndarray:
  return np.full((H, W, 3), value, np.float32)


def _scene(tmp_path):
  """A packed scene holding only test images (view ids 1, 9, 11 as grey levels 0.2, 0.4, 0.6)."""
  path = str(tmp_path / 'scene.npz')
  meta = {'version': packed.VERSION, 'splits': {'test': {'ids': IDS}}}
  images = np.stack([_flat(v) for v in (0.2, 0.4, 0.6)])
  packed.write_pack(path, {'meta': np.array(json.dumps(meta)), **packed.encode('test/images', images)})
  return path


def _renders(out, run: str, colour: float, ids=(9, 11)):
  folder = out / f'test_preds_{run}'
  folder.mkdir(parents=True)
  for view in ids:
    vis.save_png(_flat(colour), str(folder / f'color_{view:03d}.png'))
    vis.save_png(_flat(1.), str(folder / f'depth_{view:03d}.png'))


def _byte(value: float) -> int:
  """A grey level as the saved PNG holds it."""
  return int(vis.to_uint8(_flat(value))[0, 0, 0])


COLUMNS = ['test view 9', 'test view 11']  # The pictured views' column titles, wrapped over the tiles' width.


def _tile(picture, rows, r: int, c: int) -> np.ndarray:
  """The pixel at the centre of tile (r, c) of demo.grid's layout (scale 1, no title)."""
  top = demo.tiles_top(COLUMNS, W) + r * (H + demo.GAP)
  left = demo.label_width(rows) + c * (W + demo.GAP)
  return picture[top + H // 2, left + W // 2]


def test_the_ground_truth_of_the_pictured_views_comes_from_the_packed_scene(tmp_path):
  out = tmp_path / 'out'
  _renders(out, 'freenerf_bfloat16', 0.8)
  assert gpu_report.write_truth(_scene(tmp_path), str(out)) == 2
  truth = np.asarray(Image.open(out / gpu_report.TRUTH_FOLDER / 'color_011.png'))
  assert (truth == _byte(0.6)).all() and not (out / gpu_report.TRUTH_FOLDER / 'color_001.png').exists()
  small = tmp_path / 'small'                                             # Renders at half size (an eval_factor):
  (small / 'test_preds_a').mkdir(parents=True)                           # the truth follows them.
  vis.save_png(np.full((H // 2, W // 2, 3), 0.5, np.float32), str(small / 'test_preds_a' / 'color_009.png'))
  gpu_report.write_truth(_scene(tmp_path), str(small))
  assert np.asarray(Image.open(small / gpu_report.TRUTH_FOLDER / 'color_009.png')).shape == (H // 2, W // 2, 3)


def test_the_picture_labels_rows_and_columns_and_shows_the_ground_truth_first(tmp_path):
  out = tmp_path / 'out'
  _renders(out, 'freenerf_bfloat16', 0.8)
  _renders(out, 'mipnerf_bfloat16', 0.1)
  gpu_report.write_truth(_scene(tmp_path), str(out))
  drawn = gpu_report.picture(str(out), ['freenerf_bfloat16', 'mipnerf_bfloat16'])
  picture = np.asarray(Image.open(drawn).convert('RGB'))
  rows = ['ground truth', 'freenerf_bfloat16 colour', 'freenerf_bfloat16 depth', 'mipnerf_bfloat16 colour',
          'mipnerf_bfloat16 depth']
  expected = [0.4, 0.8, 1., 0.1, 1.]                                     # View 9's column, top to bottom.
  assert [int(_tile(picture, rows, r, 0)[0]) for r in range(5)] == [_byte(v) for v in expected]
  assert int(_tile(picture, rows, 0, 1)[0]) == _byte(0.6)         # View 11's truth beside it.
  top, left = demo.tiles_top(COLUMNS, W), demo.label_width(rows)
  assert picture.shape[:2] == (top + 5 * (H + demo.GAP), left + 2 * (W + demo.GAP))
  for r in range(5):                                                     # Each row's title is drawn.
    assert (picture[top + r * (H + demo.GAP):top + (r + 1) * (H + demo.GAP), :left] < 128).any()
  for c in range(2):                                                     # Each column's too.
    assert (picture[:top, left + c * (W + demo.GAP):left + (c + 1) * (W + demo.GAP)] < 128).any()


def test_without_the_ground_truth_the_runs_rows_come_first(tmp_path):
  _renders(tmp_path, 'freenerf_bfloat16', 0.8)
  picture = np.asarray(Image.open(gpu_report.picture(str(tmp_path), ['freenerf_bfloat16'])).convert('RGB'))
  assert int(_tile(picture, ['freenerf_bfloat16 colour', 'freenerf_bfloat16 depth'], 0, 0)[0]) == _byte(0.8)
  assert gpu_report.picture(str(tmp_path), ['none']) == ''
