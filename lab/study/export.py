"""Copies a study's results into a folder meant to be committed: what was run, on what, and what came out.

<dest>/ gets results.csv, the statistics over seeds (summary.csv, comparisons.csv and .md, and looks.json: the seed
counts at which the comparisons were read, lab/study/looks.py) and the plots, cells.jsonl (a line per finished
cell: its gin, its cell.json, its evaluation's metrics.json, whose run folder is written as the spec writes it,
{out}/<study>/<cell>/run, and its learning curve; a cell reused from another study's export a reference to that
export's line: lab/study/cells_file.py), a side-by-side picture per scene and render size (ground truth, then each method's render
of the first evaluated test views, of the first seed; under each, its depth, the exact depth under the ground truth
where the scene has one, each depth panel in its own colour range), table.md (per cell its metrics, wall times and
commit) and provenance.json: the command (its paths relative to the repository: internal/cli.py's recorded_command),
the study file's path and SHA-256, the machine and the package versions (each cell's commit, with the tracked files
that differed from it, is in its line). No checkpoints, no renders.
"""

import glob
import json
import os
import pathlib
import shutil
from typing import Callable, Dict, List, NamedTuple, Optional

import numpy as np
from PIL import Image

from internal import runs
from tools import provenance
from lab.study import cells_file
from lab.study import evaluations as study_evaluations
from lab.study import looks as study_looks
from lab.study import spec as study_spec

RUN_SUBDIR = 'run'    # A cell's run directory (Config.checkpoint_dir) inside its folder.
# Written by --reuse into a cell it placed: {"export": the export's absolute path}, so that an export of this study
# refers to that export's line instead of copying it when the cell is another study's.
REUSED_FILE = 'reused_from.json'
PICTURE_VIEWS = 2     # Test views per scene in the side-by-side picture.
MIN_TILE_WIDTH = 160  # Narrower renders are upscaled (nearest) so that the column titles fit.
PROVENANCE_FILE = cells_file.PROVENANCE_FILE
REPO = study_spec.REPO
TABLE_FILE = 'table.md'
# Columns of table.md, where the cells report them: DTU's object-masked metrics first, as the paper's tables.
TABLE_METRICS = ('psnr_masked', 'ssim_masked', 'lpips_masked', 'psnr', 'ssim', 'lpips', 'depth_mae',
                 'pseudo_depth_mae', 'pseudo_depth_within_5pct', 'sfm_depth_mae')


def eval_dir(cell_path: str, step: int) -> str:
  """The evaluation folder of a finished cell's run (<cell>/run/test_preds_step_<step>)."""
  return runs.eval_dir(os.path.join(cell_path, RUN_SUBDIR), step)


def _cell_line(study: study_spec.Study, cell: study_spec.Cell, path: str, record: dict, dest: str) -> dict:
  """A finished cell's line of cells.jsonl: a reference when --reuse took it from another study's export that
  still holds the same run (its path relative to dest), else its spec, record, evaluation, learning curve and
  further evaluations."""
  metrics = os.path.join(eval_dir(path, record['step']), cells_file.METRICS_FILE)
  curve = runs.curve_path(os.path.join(path, RUN_SUBDIR))
  evaluation = _portable(cells_file.read_json(metrics), path) if os.path.isfile(metrics) else None
  further = study_evaluations.recorded(path, record['step'], dict(study.evaluations))
  further = {name: {**found, 'evaluation': _portable(found['evaluation'], path)} for name, found in further.items()}
  entry = cells_file.line(cell.cell_id, record, evaluation, _text(curve), cells_file.spec(study, cell), further)
  source = _reused_from(path)
  if source and record.get('study') != study.name:
    return cells_file.reference(dest, entry, source) or entry
  return entry


def _portable(evaluation: dict, cell_path: str) -> dict:
  """A cell's metrics.json with the run folder it names, where absolute, as its spec writes it: {out}/<study>/<cell>/run,
  read from the path's last three parts, so that an out folder moved or copied since the cell ran (another checkout,
  a cluster's disk) exports no path of the machine that ran it (a cell --reuse placed names the folder of the
  export's line already: another study's)."""
  run_dir = evaluation.get('run_dir')
  parts = pathlib.PurePath(run_dir).parts if run_dir and os.path.isabs(run_dir) else ()
  if len(parts) < 4 or parts[-2:] != (os.path.basename(os.path.abspath(cell_path)), RUN_SUBDIR):
    return evaluation
  return {**evaluation, 'run_dir': '/'.join(('{out}',) + parts[-3:])}


def _text(path: str) -> Optional[str]:
  """A file's text as written (line ends kept), None when absent."""
  if not os.path.isfile(path):
    return None
  with open(path, newline='') as f:
    return f.read()


def _reused_from(cell_path: str) -> Optional[str]:
  """The export --reuse took a cell from (its REUSED_FILE), None for a cell that ran here."""
  marker = os.path.join(cell_path, REUSED_FILE)
  return cells_file.read_json(marker)['export'] if os.path.isfile(marker) else None


class Truth(NamedTuple):
  """The pictured test views as the cells' evaluation loaded them: {view id: image [H,W,3]}, {view id: exact depth
  [H,W] or None where the scene has none}, and (view id, rendered distance [H,W]) -> world depth [H,W]."""
  images: Dict[int, np.ndarray]
  depths: Dict[int, Optional[np.ndarray]]
  to_world: Callable


def _depth_row(folders: List[str], view_id: int, truth: Truth):
  """The depth row of one test view: the exact depth under the ground truth where the scene has one (else blank),
  then each evaluation's rendered depth, each panel in its own colour range (a shared range flattens a render
  whose depths span little, such as a prior's); None when an evaluation kept no depth."""
  files = [runs.depth_file(folder, view_id) for folder in folders]
  if not all(os.path.isfile(f) for f in files):
    return None
  exact = truth.depths.get(view_id)
  first = np.ones_like(truth.images[view_id]) if exact is None else runs.colorize_depth(exact)
  return [first] + [runs.colorize_depth(truth.to_world(view_id, np.load(f)['distance'])) for f in files]


def _scene_picture(cells: List[dict], paths: Dict[str, str], truth: Truth, path: str) -> None:
  """Writes one scene's picture: per test view (by id) a colour row and, where kept, a depth row; columns ground
  truth then each cell's render."""
  folders = [eval_dir(paths[c['cell']], c['step']) for c in cells]
  rows, row_titles = [], []
  for view_id, image in truth.images.items():
    renders = [np.asarray(Image.open(os.path.join(folder, f'color_{view_id:03d}.png')).convert('RGB')) / 255.
               for folder in folders]
    rows.append([image] + renders)
    row_titles.append(f'test view {view_id}')
    depth = _depth_row(folders, view_id, truth)
    if depth is not None:
      rows.append(depth)
      row_titles.append('depth')
  one_method = len({c['method'] for c in cells}) == 1
  titles = [' '.join(([] if one_method and c['labels'] else [c['method']]) +
                     [f'{k}={v}' for k, v in c['labels'].items()]) for c in cells]
  scale = -(-MIN_TILE_WIDTH // rows[0][0].shape[1])
  runs.save_picture(runs.grid(rows, ['ground truth'] + titles, row_titles, scale=scale), path)


def _ground_truth(cell_path: str, cell: dict, count: int) -> Truth:
  """The first `count` test views the cell evaluated, loaded as its evaluation did (with exact depths where the
  scene has them)."""
  with study_spec.cell_config(cell_path) as config:
    views = runs.test_views(config)
  metrics = cells_file.read_json(os.path.join(eval_dir(cell_path, cell['step']), cells_file.METRICS_FILE))
  at = {i: views.ids.index(i) for i in [entry['id'] for entry in metrics['per_image'][:count]]}
  depths = {i: None if views.depths is None else np.asarray(views.depths[k]) for i, k in at.items()}
  return Truth({i: np.asarray(views.images[k]) for i, k in at.items()}, depths,
               lambda i, distance: views.world_depth(at[i], distance))


def checkout_path(path: str) -> str:
  """path relative to the git checkout that holds it (a worktree's own, not the one whose code runs), else to REPO."""
  folder = os.path.dirname(os.path.abspath(path))
  while not os.path.exists(os.path.join(folder, '.git')) and os.path.dirname(folder) != folder:
    folder = os.path.dirname(folder)
  root = folder if os.path.exists(os.path.join(folder, '.git')) else REPO
  return os.path.relpath(os.path.abspath(path), root)


def markdown_table(cells: List[dict]) -> str:
  """table.md: a row per cell with its labels, metrics (3 decimals), wall times in minutes and short commit."""
  metrics = [m for m in TABLE_METRICS if any(c['means'].get(m) is not None for c in cells)]
  labels = list(dict.fromkeys(k for c in cells for k in c['labels']))
  head = ['method', 'scene'] + labels + ['step'] + metrics + ['train min', 'eval min', 'commit']
  lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
  for c in cells:
    values = [c['method'], c['scene']] + [str(c['labels'].get(k, '')) for k in labels] + [str(c['step'])]
    values += ['' if c['means'].get(m) is None else f'{c["means"][m]:.3f}' for m in metrics]
    values += [f'{c["train_seconds"] / 60:.1f}', f'{c["eval_seconds"] / 60:.1f}', (c.get('commit') or '')[:8]]
    lines.append('| ' + ' | '.join(values) + ' |')
  return '\n'.join(lines) + '\n'


def _seeds(study: study_spec.Study) -> list:
  """The labels of the study's seeds in axis order, [None] for a study without a seed axis."""
  axis = next((a for a in study.axes if a.name == study_spec.SEED_AXIS), None)
  return [p.label for p in axis.points] if axis else [None]


def _has_renders(cell_path: str, cell: dict) -> bool:
  """Whether a finished cell kept what a picture is drawn from (its settings and its evaluation's images); a
  cell.json copied in from an export has neither."""
  images = glob.glob(os.path.join(eval_dir(cell_path, cell['step']), 'color_*.png'))
  return bool(images) and study_spec.has_cell_spec(cell_path)


def _picture_cells(cells: List[dict], paths: Dict[str, str], seeds: list) -> List[dict]:
  """The cells of the first seed whose every finished cell has its renders ([] when no seed has)."""
  for seed in seeds:
    chosen = [c for c in cells if c['labels'].get(study_spec.SEED_AXIS) == seed]
    if chosen and all(_has_renders(paths[c['cell']], c) for c in chosen):
      return chosen
  return []


def _render_size(cell_path: str, cell: dict) -> tuple:
  """(height, width) of a finished cell's renders."""
  first = sorted(glob.glob(os.path.join(eval_dir(cell_path, cell['step']), 'color_*.png')))[0]
  with Image.open(first) as image:
    return image.height, image.width


def _by_render_size(scene: str, cells: List[dict], paths: Dict[str, str]) -> List[tuple]:
  """[(picture name, cells)] of one scene's pictured cells, one picture per size of their renders (a study that
  varies the image size): side_by_side_<scene>.png for the first cell's size, side_by_side_<scene>_<H>x<W>.png for
  others, each with the ground truth of its own size."""
  groups = {}
  for cell in cells:
    groups.setdefault(_render_size(paths[cell['cell']], cell), []).append(cell)
  first = next(iter(groups))
  return [(f'side_by_side_{scene}.png' if size == first else f'side_by_side_{scene}_{size[0]}x{size[1]}.png', group)
          for size, group in groups.items()]


def export(study: study_spec.Study, study_file: str, study_folder: str, dest: str, command: str) -> List[str]:
  """Copies the study's finished cells, results and plots into dest (absent or empty); returns the pictures written.

  Written into a hidden folder beside dest and renamed to dest at the end, so that an export that fails half-way
  leaves no partial dest behind (one that would block the retry, or pass for a whole export).
  """
  dest = os.path.normpath(dest)
  staging = os.path.join(os.path.dirname(os.path.abspath(dest)), f'.{os.path.basename(dest)}.partial')
  shutil.rmtree(staging, ignore_errors=True)
  try:
    pictures = _write(study, study_file, study_folder, staging, command)
  except BaseException:
    shutil.rmtree(staging, ignore_errors=True)
    raise
  if os.path.isdir(dest):
    os.rmdir(dest)  # Empty: the runner refuses a dest with anything in it.
  os.rename(staging, dest)
  return [os.path.join(dest, os.path.relpath(path, staging)) for path in pictures]


def _write(study: study_spec.Study, study_file: str, study_folder: str, dest: str, command: str) -> List[str]:
  """The export itself, into dest; returns the pictures written."""
  os.makedirs(dest, exist_ok=True)
  for name in sorted(os.listdir(study_folder)):
    if name.endswith(('.csv', '.png', '.md')) or name == study_looks.FILE:
      shutil.copy2(os.path.join(study_folder, name), dest)
  finished, paths, lines = [], {}, []
  for cell in study_spec.cells(study):
    path = os.path.join(study_folder, cell.cell_id)
    if os.path.isfile(os.path.join(path, 'cell.json')):
      finished.append(cells_file.read_json(os.path.join(path, 'cell.json')))
      paths[cell.cell_id] = path
      lines.append(_cell_line(study, cell, path, finished[-1], dest))  # Beside the final dest: same references.
  cells_file.write(dest, lines)
  pictures = []
  for scene in dict.fromkeys(c['scene'] for c in finished):
    cells = _picture_cells([c for c in finished if c['scene'] == scene], paths, _seeds(study))
    if not cells:
      print(f'warning: side_by_side_{scene}.png not drawn: no seed has every finished cell with its renders '
            f'(color_*.png) and cell_spec.json')
      continue
    for name, group in _by_render_size(scene, cells, paths):
      pictures.append(os.path.join(dest, name))
      _scene_picture(group, paths, _ground_truth(paths[group[0]['cell']], group[0], PICTURE_VIEWS), pictures[-1])
  with open(os.path.join(dest, TABLE_FILE), 'w') as f:
    f.write(markdown_table(finished))
  record = {'command': command, 'machine': provenance.machine(),
            'study_file': {'path': checkout_path(study_file),
                           'sha256': provenance.file_sha256(study_file)}}
  with open(os.path.join(dest, PROVENANCE_FILE), 'w') as f:
    json.dump(record, f, indent=1)
  return pictures
