"""How a study's rendered depths match the generated scene's exact depths in shape, not only in value.

  python -m tools.depth_shape studies/depth_prior_generated.toml --out out/studies --export DIR [--also FOLDER ...]

A prior known only up to scale and shift (a monocular depth map) can fix the order and shape of the rendered
depths but not their overall offset, which the study's depth_mae mixes in. Per cell and test view this reads the
newest evaluation's rendered depths (depth_<id>.npz, converted to world depths as depth_mae is) and the exact
depths, and reports over the pixels that hit the scene: `corr`, the Pearson correlation of the two; `median_ratio`,
rendered over exact median depth; `mae_affine`, the mean absolute error left after the least-squares scale and
shift of the rendered depths onto the exact ones; `mae`, before it. A cell's value is the mean over the
views its evaluation rendered (all test views, or those of Config.eval_test_ids); the study's [[compare]] entries pair
them over seeds with Student's t intervals, corrected for the study's looks as its comparisons.md is
(tools/study/looks.py). Writes
DIR/depth_shape.csv (per cell and view), DIR/depth_shape.md (means per method and the comparisons) and
DIR/depth_shape.json (provenance). --also: other studies' folders whose cells of the same name stand in for
cells without renders here (cells a study reused from an export have none).
"""

import argparse
import csv
import glob
import io
import json
import os
import re
import statistics
import sys

import gin
import numpy as np

from internal import atomic
from internal import cli
from internal import config_loader
from internal.datasets import load_dataset, loader
from internal.evaluation import depth_metrics
from tools import provenance
from tools.study import looks as study_looks
from tools.study import runner
from tools.study import spec as study_spec
from tools.study import stats as study_stats

METRICS = (('corr', False), ('median_ratio', None), ('mae_affine', True), ('mae', True))  # (name, lower better).


def view_shape(rendered: np.ndarray, exact: np.ndarray) -> dict:
  """{corr, median_ratio, mae_affine, mae} of rendered vs exact depths [H,W] over the pixels that hit (exact > 0)."""
  hit = exact > 0
  r, e = rendered[hit].astype(np.float64), exact[hit].astype(np.float64)
  design = np.stack([r, np.ones_like(r)], -1)
  fitted = design @ np.linalg.lstsq(design, e, rcond=None)[0]
  return {'corr': float(np.corrcoef(r, e)[0, 1]), 'median_ratio': float(np.median(r) / np.median(e)),
          'mae_affine': float(np.abs(fitted - e).mean()), 'mae': float(np.abs(r - e).mean())}


def cell_rows(folder: str, labels: dict) -> list:
  """Rows (labels, view, METRICS) of one cell folder's newest evaluation; [] when it has no renders or no settings
  (a cell reused from an export keeps neither)."""
  evaluations = glob.glob(os.path.join(folder, runner.RUN_SUBDIR, 'test_preds_step_*'))
  spec_path = os.path.join(folder, runner.SPEC_FILE)
  if not evaluations or not os.path.isfile(spec_path):
    return []
  newest = max(evaluations, key=lambda d: int(re.search(r'(\d+)$', d).group(1)))
  with open(spec_path) as f:
    spec = json.load(f)
  gin.clear_config()
  config = config_loader.load_config(spec['gin_configs'], spec['gin_bindings'])
  test = load_dataset('test', config, ground_truth=True)
  ndc = loader.REGISTRY[loader.filed_as(config)[0]].ndc(config)
  rows = []
  for i, view in enumerate(test.ids):
    path = depth_metrics.depth_file(newest, int(view))
    if os.path.isfile(path):  # Config.eval_test_ids: the evaluation rendered only some test views.
      with np.load(path) as f:
        rendered = depth_metrics.world_depth(test, i, f['distance'], ndc)
      rows.append({**labels, 'view': int(view), **view_shape(rendered, test.depths[i])})
  if not rows:
    raise ValueError(f'{newest}: no depth_<id>.npz of the test views {[int(v) for v in test.ids]}; expected an '
                     'evaluation that kept its rendered depths (evaluate the cell again with this version)')
  return rows


def _table(study, rows: list) -> str:
  """Markdown: the test views, the mean (std) over cells of each metric per method, then the paired comparisons
  (their intervals corrected for the study's looks)."""
  per_cell = {}
  for row in rows:
    per_cell.setdefault(row['cell'], []).append(row)
  cells = [{**group[0], **{m: statistics.fmean(r[m] for r in group) for m, _ in METRICS}}
           for group in per_cell.values()]
  views = {c: sorted(r['view'] for r in group) for c, group in per_cell.items()}
  lines = [f'Test views (those each cell\'s evaluation rendered): {_views_text(views)}', '',
           '| method | n | ' + ' | '.join(m for m, _ in METRICS) + ' |', '|---|---|' + '---|' * len(METRICS)]
  for method in study.methods:
    values = [c for c in cells if c['method'] == method.name]
    if values:
      lines.append(f'| {method.name} | {len(values)} | ' + ' | '.join(
          f'{statistics.fmean(c[m] for c in values):.3f} ({statistics.pstdev([c[m] for c in values]):.3f})'
          for m, _ in METRICS) + ' |')
  comparisons, level = [], study_stats.look_level(study)
  for metric, lower in METRICS:
    for entry in study.compare:
      differences = study_stats.pairs(study, cells, entry, metric)
      if differences and lower is not None:
        comparisons.append(study_stats.Comparison(entry.axis, entry.a, entry.b, metric, len(differences),
                                                  *study_stats.t_interval(differences, level), lower, level))
  return '\n'.join(lines) + '\n\n' + runner.comparisons_markdown(study, comparisons)


def _views_text(views: dict) -> str:
  """'[0, 1, 2] in every cell', or per cell its views when they differ (the means are then over other views)."""
  if len({tuple(v) for v in views.values()}) == 1:
    return f'{next(iter(views.values()))} in every cell'
  return ('they differ, so the cells\' means are over different views: ' +
          '; '.join(f'{cell} {v}' for cell, v in views.items()))


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  argv = sys.argv[1:] if argv is None else list(argv)
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('study', help='the study file')
  parser.add_argument('--out', default='out/studies', help='the folder holding the study\'s folder')
  parser.add_argument('--export', required=True, help='the folder to write depth_shape.{csv,md,json} into')
  parser.add_argument('--also', nargs='*', default=[], help='other study folders to take renders of cells from')
  args = parser.parse_args(argv)
  study = study_spec.load(args.study)
  study = study_looks.with_recorded(study, runner.study_dir(study, args.out))
  rows = []
  for cell in study_spec.cells(study):
    labels = {'cell': cell.cell_id, 'method': cell.method, 'scene': cell.scene, **cell.labels()}
    for folder in [runner.cell_dir(study, cell, args.out)] + [os.path.join(f, cell.cell_id) for f in args.also]:
      found = cell_rows(folder, labels) if os.path.isdir(folder) else []
      if found:
        rows.extend(found)
        break
  if not rows:
    raise ValueError(f'no cell of {args.study!r} under {args.out!r} has an evaluation with depths')
  os.makedirs(args.export, exist_ok=True)
  text = io.StringIO()
  writer = csv.DictWriter(text, fieldnames=list(rows[0]))
  writer.writeheader()
  writer.writerows(rows)
  atomic.write_text(os.path.join(args.export, 'depth_shape.csv'), text.getvalue())
  atomic.write_text(os.path.join(args.export, 'depth_shape.md'), _table(study, rows))
  record = provenance.record(['python', '-m', 'tools.depth_shape', *argv])
  atomic.write_text(os.path.join(args.export, 'depth_shape.json'), json.dumps(record, indent=1) + '\n')
  print(_table(study, rows))
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
