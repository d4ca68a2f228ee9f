"""Finished cells taken from an earlier export (`tools.study --reuse DIR`), so that a study moved to another machine,
or whose run folders are gone, runs only the cells it lacks.

A cell of the export is reused when the cell has not finished here and the study file the export ran (named in its
provenance.json by path and SHA-256, found in this checkout or its git history) gives it the same gin configs and
bindings as this study file does. Its numbers are the evaluation's: the export's cell.json
must agree with the metrics.json beside it (step, completeness and every mean), else the command stops with one line
naming both files; a cell exported without metrics.json is not reused (it runs here). Its cell.json, the evaluation's metrics.json and
metrics.csv and its learning curve go where a run here would have written them; its checkpoints and renders are not
in an export, so a reused cell cannot resume training and appears in no side-by-side picture.
"""

import json
import os
import shutil
from typing import List, Optional

from tools import provenance
from tools.study import export as study_export
from tools.study import spec as study_spec


def exported_study(export_dir: str) -> study_spec.Study:
  """The study file an export ran: the one its provenance.json names by path and SHA-256, read from this checkout
  or its git history. StudyError naming the folder when there is no such record or file."""
  provenance_path = os.path.join(export_dir, study_export.PROVENANCE_FILE)
  if not os.path.isfile(provenance_path):
    raise study_spec.StudyError(f'--reuse {export_dir}: no {study_export.PROVENANCE_FILE} there; give the folder '
                                'that tools.study --export wrote')
  source = study_export.read_json(provenance_path).get('study_file') or {}
  if not {'path', 'sha256'} <= source.keys():
    raise study_spec.StudyError(f'--reuse {export_dir}: its {study_export.PROVENANCE_FILE} names no study file '
                                '(path and sha256); export it again with this version of tools.study')
  text = provenance.file_at(study_export.REPO, source['path'], source['sha256'])
  if text is None:
    raise study_spec.StudyError(f"--reuse {export_dir}: it ran {source['path']} of SHA-256 {source['sha256'][:12]}..., "
                                'which neither that file here nor its git history holds')
  return study_spec.parse(text, source['path'])


def _same_settings(study, exported, cell, out: str, data_root: str) -> bool:
  """Whether both study files give the cell (one of both studies') the same gin configs and bindings."""
  run_dir = os.path.join(out, cell.cell_id)
  return (study_spec.cell_gin(study, cell, out, data_root, run_dir)
          == study_spec.cell_gin(exported, cell, out, data_root, run_dir))


def _copy_cell(source: str, target: str, step: int) -> None:
  """Places an exported cell's files in the cell folder target as a finished run would have left them."""
  from internal.evaluation import learning_curve  # pylint: disable=import-outside-toplevel  (jax: only when used)
  evaluated = study_export.eval_dir(target, step)
  os.makedirs(evaluated, exist_ok=True)
  curve = learning_curve.csv_path(os.path.join(target, study_export.RUN_SUBDIR))
  destinations = [os.path.join(evaluated, name) for name in study_export.METRICS_FILES] + [curve]
  for dest in destinations:
    exported = os.path.join(source, os.path.basename(dest))
    if os.path.isfile(exported):
      shutil.copy2(exported, dest)
  shutil.copy2(os.path.join(source, 'cell.json'), target)  # Last: cell.json marks the cell finished.


def checked_record(source: str) -> Optional[dict]:
  """The exported cell.json of folder source once checked against its metrics.json; None without metrics.json.
  ValueError naming both files when they disagree."""
  record = study_export.read_json(os.path.join(source, 'cell.json'))
  metrics_path = os.path.join(source, 'metrics.json')
  if not os.path.isfile(metrics_path):
    return None
  metrics = study_export.read_json(metrics_path)
  for key in ('step', 'complete', 'means'):
    if json.dumps(record.get(key), sort_keys=True) != json.dumps(metrics.get(key), sort_keys=True):
      differ = _first_difference(record.get(key), metrics.get(key))
      raise ValueError(f'--reuse: {os.path.join(source, "cell.json")} says {key} {differ[0]} but the evaluation\'s '
                       f'{metrics_path} says {differ[1]}; expected the numbers the evaluation wrote (restore the '
                       'export from git, or delete that cell\'s folder from the export to run it here)')
  return record


def _first_difference(a, b) -> tuple:
  """('psnr 42.0', 'psnr 10.48') for the first mean that differs between two dicts of means; else (a, b)."""
  if isinstance(a, dict) and isinstance(b, dict):
    for name in sorted(set(a) | set(b)):
      if json.dumps(a.get(name)) != json.dumps(b.get(name)):
        return f'{name} {a.get(name)}', f'{name} {b.get(name)}'
  return a, b


def reuse(study: study_spec.Study, export_dir: str, study_folder: str, data_root: str) -> List[str]:
  """Copies the export's finished cells that this study lacks and has with the same settings; prints a line per
  cell reused or passed over; returns the reused cell ids."""
  exported = exported_study(export_dir)
  exported_ids = {c.cell_id for c in study_spec.cells(exported)}
  out = os.path.dirname(study_folder)
  chosen = []
  for cell in study_spec.cells(study):
    source, target = os.path.join(export_dir, cell.cell_id), os.path.join(study_folder, cell.cell_id)
    if not os.path.isfile(os.path.join(source, 'cell.json')) or os.path.isfile(os.path.join(target, 'cell.json')):
      continue
    if cell.cell_id not in exported_ids or not _same_settings(study, exported, cell, out, data_root):
      print(f'warning: {cell.cell_id} not reused: {export_dir} ran it with other settings')
      continue
    record = checked_record(source)
    if record is None:
      print(f'warning: {cell.cell_id} not reused: {source} has no metrics.json to check its cell.json against')
      continue
    chosen.append((cell, source, target, record))
  reused = []
  for cell, source, target, record in chosen:  # Copied once every cell is checked: a bad export copies nothing.
    _copy_cell(source, target, record['step'])
    reused.append(cell.cell_id)
    print(f'reused {cell.cell_id} from {export_dir} (commit {(record.get("commit") or "unknown")[:8]})')
  return reused
