"""Finished cells taken from an earlier export (`lab.study --reuse DIR`), so that a study moved to another machine,
or whose run folders are gone, runs only the cells it lacks.

A cell of the export (its line of cells.jsonl: lab/study/cells_file.py) is reused when the cell has not finished
here and the study file the export ran (named in its provenance.json by path and SHA-256, found in this checkout or
its git history) gives it the same settings as this study file does:
the same gin configs and bindings, or ones that load to the same Config (T given in steps or as a fraction, say).
Its numbers are the evaluation's: the cell's record must agree with its evaluation's metrics.json (step,
completeness and every mean), else the command stops with one line naming both; a cell exported without its
evaluation is not reused (it runs here). Its cell.json, the evaluation's metrics.json and metrics.csv, its
learning curve and its further evaluations (lab/study/evaluations.py) go where a run here would have written them, with a note of the export it came from (an export of
this study then refers to that export's line); its checkpoints and renders are not in an export, so a reused cell
cannot resume training and appears in no side-by-side picture. An export of the same study passes on its looks (the
seed counts at which its comparisons were read, lab/study/looks.py), so that its intervals stay corrected for them.
"""

import json
import os
from typing import List, Optional

from internal import atomic
from internal import runs
from tools import provenance
from lab.study import cells_file
from lab.study import evaluations as study_evaluations
from lab.study import export as study_export
from lab.study import looks as study_looks
from lab.study import spec as study_spec


def exported_study(export_dir: str) -> study_spec.Study:
  """The study file an export ran: the one its provenance.json names by path and SHA-256, read from this checkout
  or its git history. StudyError naming the folder when there is no such record or file."""
  provenance_path = os.path.join(export_dir, study_export.PROVENANCE_FILE)
  if not os.path.isfile(provenance_path):
    raise study_spec.StudyError(f'--reuse {export_dir}: no {study_export.PROVENANCE_FILE} there; give the folder '
                                'that lab.study --export wrote')
  source = cells_file.read_json(provenance_path).get('study_file') or {}
  if not {'path', 'sha256'} <= source.keys():
    raise study_spec.StudyError(f'--reuse {export_dir}: its {study_export.PROVENANCE_FILE} names no study file '
                                '(path and sha256); export it again with this version of lab.study')
  text = next(filter(None, (provenance.file_at(study_export.REPO, path, source['sha256'])
                            for path in _paths_here(source['path']))), None)
  if text is None:
    raise study_spec.StudyError(f"--reuse {export_dir}: it ran {source['path']} of SHA-256 {source['sha256'][:12]}..., "
                                'which neither that file here nor its git history holds')
  return study_spec.parse(text, source['path'])


def _paths_here(path: str) -> List[str]:
  """The path a provenance.json names, then, for one outside this checkout (another worktree's,
  '../wt-x/studies/<file>'), its tails inside it ('wt-x/studies/<file>', 'studies/<file>', '<file>'): the file's
  SHA-256 decides which, if any, is the study file that ran."""
  parts = os.path.normpath(path).split(os.sep)
  if parts[0] != os.pardir and not os.path.isabs(path):
    return [path]
  parts = [p for p in parts if p not in (os.pardir, '')]
  return [path] + [os.path.join(*parts[i:]) for i in range(len(parts))]


def _same_settings(study, exported, cell, out: str, data_root: str) -> bool:
  """Whether both study files give the cell (one of both studies') the same gin configs and bindings, or gin that
  loads to the same Config (the run's fingerprint)."""
  run_dir = os.path.join(out, cell.cell_id)
  ours = study_spec.cell_gin(study, cell, out, data_root, run_dir)
  theirs = study_spec.cell_gin(exported, cell, out, data_root, run_dir)
  if ours == theirs:
    return True
  fingerprint = _fingerprint(*ours)
  return fingerprint is not None and fingerprint == _fingerprint(*theirs)


def _fingerprint(configs: list, bindings: list) -> Optional[dict]:
  """The fingerprint of the Config that gin loads to (internal/run/run_dir.py), None when it does not load."""
  try:
    with runs.fresh_config(configs, bindings) as config:
      return runs.fingerprint(config)
  except (ValueError, OSError, KeyError, TypeError):
    return None


def _place(entry: cells_file.Entry, target: str) -> None:
  """Writes an exported cell's files into the cell folder target as a finished run would have left them."""
  texts = cells_file.files(entry.line)
  evaluated = study_export.eval_dir(target, entry.line['record']['step'])
  os.makedirs(evaluated, exist_ok=True)
  curve_folder = os.path.dirname(runs.curve_path(os.path.join(target, study_export.RUN_SUBDIR)))
  places = {cells_file.METRICS_FILE: evaluated, cells_file.METRICS_TABLE: evaluated, cells_file.CURVE_FILE: curve_folder}
  for name, folder in places.items():
    if name in texts:
      atomic.write_text(os.path.join(folder, name), texts[name])
  study_evaluations.place(target, entry.line['record']['step'], entry.line.get('evaluations', {}))
  atomic.write_text(os.path.join(target, study_export.REUSED_FILE),
                    json.dumps({'export': os.path.abspath(entry.export)}))
  atomic.write_text(os.path.join(target, cells_file.CELL_FILE), texts[cells_file.CELL_FILE])  # Last: finished.


def checked(entry: cells_file.Entry) -> bool:
  """Whether an exported cell has its evaluation (False: not reused); ValueError naming where its record and its
  evaluation were read when they disagree on the step, completeness or a mean."""
  record, metrics = entry.line['record'], entry.line.get('evaluation')
  if metrics is None:
    return False
  for key in ('step', 'complete', 'means'):
    if json.dumps(record.get(key), sort_keys=True) != json.dumps(metrics.get(key), sort_keys=True):
      differ = _first_difference(record.get(key), metrics.get(key))
      raise ValueError(f'--reuse: {entry.where["record"]} says {key} {differ[0]} but the evaluation\'s '
                       f'{entry.where["evaluation"]} says {differ[1]}; expected the numbers the evaluation wrote '
                       '(restore the export from git, or delete that cell from the export to run it here)')
  return True


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
  entries = cells_file.read(export_dir)
  out = os.path.dirname(study_folder)
  chosen = []
  for cell in study_spec.cells(study):
    entry, target = entries.get(cell.cell_id), os.path.join(study_folder, cell.cell_id)
    if entry is None or os.path.isfile(os.path.join(target, cells_file.CELL_FILE)):
      continue
    if cell.cell_id not in exported_ids or not _same_settings(study, exported, cell, out, data_root):
      print(f'warning: {cell.cell_id} not reused: {export_dir} ran it with other settings')
      continue
    if not checked(entry):
      print(f'warning: {cell.cell_id} not reused: {entry.where["evaluation"]} is missing, so its record cannot '
            'be checked against it')
      continue
    chosen.append((cell, entry, target))
  if exported.name == study.name and study_looks.recorded(export_dir):
    os.makedirs(study_folder, exist_ok=True)
    study_looks.record(study_folder, study_looks.recorded(export_dir))
  reused = []
  for cell, entry, target in chosen:  # Written once every cell is checked: a bad export writes nothing.
    _place(entry, target)
    reused.append(cell.cell_id)
    print(f'reused {cell.cell_id} from {export_dir} (commit {(entry.line["record"].get("commit") or "unknown")[:8]})')
  return reused
