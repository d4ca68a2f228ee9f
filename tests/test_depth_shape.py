"""tools.depth_shape: the correlation, median ratio and the error left after the best scale and shift, by hand; a
study whose cells evaluated some of the test views."""

import csv
import json
import os
import pathlib

import numpy as np
import pytest

from internal.configs import Config
from internal.datasets import load_dataset
from internal.evaluation import depth_metrics
from tools import depth_shape

REPO = pathlib.Path(__file__).resolve().parents[1]
STUDY = '''
name = "mini"
seeds = 2
[methods.freenerf]
configs = ["{demo}"]
[scenes.object]
bindings = ["Config.data_dir = '{data}'"]
'''


def test_an_affine_map_of_the_truth_has_correlation_one_and_no_error_after_the_fit():
  exact = np.array([[2., 3., 0.], [4., 6., 5.]])  # 0: a pixel that hits nothing, left out.
  shape = depth_shape.view_shape(.5 * exact + 1., exact)
  assert shape['corr'] == pytest.approx(1.) and shape['mae_affine'] == pytest.approx(0., abs=1e-12)
  hit = exact[exact > 0]
  assert shape['mae'] == pytest.approx(np.abs(.5 * hit + 1. - hit).mean())
  assert shape['median_ratio'] == pytest.approx((.5 * 4. + 1.) / 4.)


def test_a_reversed_depth_has_correlation_minus_one_and_the_fit_removes_nothing_of_a_constant():
  exact = np.array([[1., 2., 3., 4.]])
  assert depth_shape.view_shape(5. - exact, exact)['corr'] == pytest.approx(-1.)
  flat = depth_shape.view_shape(np.array([[1., 1., 1., 3.]]), exact)  # The fit is the best line, by hand.
  x, y = np.array([1., 1., 1., 3.]), exact[0]
  a, b = np.polyfit(x, y, 1)
  assert flat['mae_affine'] == pytest.approx(np.abs(a * x + b - y).mean())


def test_a_study_whose_cells_evaluated_some_test_views_reports_those(tmp_path, capsys):
  """Cells of a study evaluated with Config.eval_test_ids = [0, 2] kept depth_000.npz and depth_002.npz only: the shapes
  are of those views, and the table says which."""
  (tmp_path / 'mini.toml').write_text(STUDY.format(demo=REPO / 'configs' / 'demo.gin', data=tmp_path / 'scene'))
  for seed in (0, 1):
    cell = tmp_path / 'out' / 'mini' / f'freenerf__object__seed={seed}'
    evaluation = cell / 'run' / 'test_preds_step_4'
    evaluation.mkdir(parents=True)
    spec = {'gin_configs': [str(REPO / 'configs' / 'demo.gin')],
            'gin_bindings': [f"Config.data_dir = '{tmp_path / 'scene'}'", 'Config.generated_size = (12, 16)']}
    (cell / 'cell_spec.json').write_text(json.dumps(spec))
    config = Config(data_dir=str(tmp_path / 'scene'), generated_size=(12, 16))
    test = load_dataset('test', config, ground_truth=True)
    for view in (0, 2):
      np.savez(depth_metrics.depth_file(str(evaluation), view), distance=.5 * test.depths[view] + 1.,
               acc=np.ones_like(test.depths[view]))
  assert depth_shape.main([str(tmp_path / 'mini.toml'), '--out', str(tmp_path / 'out'),
                           '--export', str(tmp_path / 'export')]) == 0
  with open(tmp_path / 'export' / 'depth_shape.csv', newline='') as f:
    rows = list(csv.DictReader(f))
  assert [(r['cell'][-6:], r['view']) for r in rows] == [('seed=0', '0'), ('seed=0', '2'), ('seed=1', '0'),
                                                         ('seed=1', '2')]
  assert all(float(r['corr']) == pytest.approx(1.) for r in rows)
  table = (tmp_path / 'export' / 'depth_shape.md').read_text()
  assert "Test views (those each cell's evaluation rendered): [0, 2] in every cell" in table
  os.remove(depth_metrics.depth_file(str(tmp_path / 'out' / 'mini' / 'freenerf__object__seed=1' / 'run' /
                                         'test_preds_step_4'), 2))
  depth_shape.main([str(tmp_path / 'mini.toml'), '--out', str(tmp_path / 'out'), '--export', str(tmp_path / 'again')])
  assert 'they differ, so the cells\' means are over different views: freenerf__object__seed=0 [0, 2]; ' \
         'freenerf__object__seed=1 [0]' in (tmp_path / 'again' / 'depth_shape.md').read_text()
  os.remove(depth_metrics.depth_file(str(tmp_path / 'out' / 'mini' / 'freenerf__object__seed=1' / 'run' /
                                         'test_preds_step_4'), 0))
  with pytest.raises(ValueError, match=r'seed=1/run/test_preds_step_4: no depth_<id>.npz of the test views \[0, 1, '
                                       r'2, 3, 4, 5, 6, 7\]; expected an evaluation that kept its rendered depths'):
    depth_shape.main([str(tmp_path / 'mini.toml'), '--out', str(tmp_path / 'out'), '--export', str(tmp_path / 'x')])
