"""A study export's side-by-side picture shows depth a reader can read (issue 59): the exact depth under the ground
truth where the scene has one, and each rendered depth in its own colour range, so that a render whose depths span
little (a depth prior's) still shows its structure."""

import numpy as np
from PIL import Image

from internal.evaluation import vis
from tools.study import export

H, W = 6, 8


def _evaluation(folder, distance) -> str:
  """An evaluation folder holding one test view's rendered distance, as eval writes it."""
  folder.mkdir()
  np.savez(folder / 'depth_000.npz', distance=distance, acc=np.ones_like(distance))
  return str(folder)


def test_each_depth_panel_has_its_own_range_and_the_exact_depth_comes_first(tmp_path):
  ramp = np.linspace(1., 3., W)[None].repeat(H, 0)
  flat = 2. + 0.01 * ramp  # Spans 0.02: in a range shared with the ramp it would be one colour.
  folders = [_evaluation(tmp_path / 'a', ramp), _evaluation(tmp_path / 'b', flat)]
  truth = export.Truth({0: np.full((H, W, 3), .5)}, {0: ramp + 1.}, lambda view, distance: distance)
  exact, wide, narrow = export._depth_row(folders, 0, truth)  # pylint: disable=protected-access
  colours = lambda panel: len(np.unique(panel.reshape(-1, 3).round(3), axis=0))  # pylint: disable=C3001
  assert colours(exact) == colours(wide) == W
  assert colours(narrow) == W  # Its own range: the 0.02 it spans is the whole colour map.
  shared = vis.colorize_depth(flat, vis.depth_range(np.concatenate([ramp.ravel(), flat.ravel()])))
  spread = lambda panel: np.ptp(panel.reshape(-1, 3), axis=0).max()  # pylint: disable=C3001
  assert spread(shared) < .05 < .5 < spread(narrow)  # A range shared with the ramp showed it in one colour.


def test_without_exact_depths_the_panel_under_the_ground_truth_is_blank(tmp_path):
  folders = [_evaluation(tmp_path / 'a', np.ones((H, W)))]
  truth = export.Truth({0: np.full((H, W, 3), .5)}, {0: None}, lambda view, distance: distance)
  blank, _ = export._depth_row(folders, 0, truth)  # pylint: disable=protected-access
  assert (blank == 1.).all()


def test_a_picture_is_a_palette_png_exact_where_it_can_be(tmp_path):
  few = np.repeat(np.linspace(0., 1., 16)[None, :, None], 3, 2).repeat(4, 0)  # 16 greys: kept exactly.
  vis.save_picture(few, str(tmp_path / 'few.png'))
  with Image.open(tmp_path / 'few.png') as saved:
    assert saved.mode == 'P' and (np.asarray(saved.convert('RGB')) == vis.to_uint8(few)).all()
  rows = np.random.default_rng(0).random((64, 96, 3))  # A render's many colours, on a white page.
  page = np.ones((80, 112, 3))
  page[8:72, 8:104] = rows
  vis.save_picture(page, str(tmp_path / 'many.png'))
  vis.save_png(page, str(tmp_path / 'full.png'))
  with Image.open(tmp_path / 'many.png') as saved:
    got = np.asarray(saved.convert('RGB')).astype(int)
  assert (got[:8] == 255).all() and np.abs(got - vis.to_uint8(page)).mean() < 10
  assert (tmp_path / 'many.png').stat().st_size < (tmp_path / 'full.png').stat().st_size / 2
