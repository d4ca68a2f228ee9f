"""An export's cells in one file, cells.jsonl: a line per finished cell with what it ran, what it measured and
where; a cell that came from another study's export is a reference to that export's line, not a copy.

A line is {"cell": id, "spec": {"gin_configs", "gin_bindings"} (templates {out} and {data_root} left in),
"record": the cell's cell.json (means, wall times, steps/s, GFLOP per step, peak memory, commit, changed files,
machine), "evaluation": its metrics.json (per view and means; metrics.csv is its per_image as a table),
"learning_curve": {"columns", "rows"} where the run recorded one, "evaluations": {name: {"bindings", "evaluation"}}
where the study asked for further evaluations (lab/study/evaluations.py)}; or {"cell": id, "same_as": "../other_export"}.
"""

import csv
import io
import json
import os
from typing import Dict, List, NamedTuple, Optional

from internal import atomic

CELLS_FILE = 'cells.jsonl'
CELL_FILE = 'cell.json'
METRICS_FILE = 'metrics.json'
METRICS_TABLE = 'metrics.csv'
CURVE_FILE = 'learning_curve.csv'  # internal/evaluation/learning_curve.py's CSV_FILE (jax-free here).
PROVENANCE_FILE = 'provenance.json'
# The parts of a line and the JSON type each must have.
LINE_TYPES = {'cell': str, 'same_as': str, 'spec': dict, 'record': dict, 'evaluation': dict, 'learning_curve': dict,
              'evaluations': dict}
JSON_NAMES = {str: 'a string', dict: 'an object', list: 'an array', int: 'a number', float: 'a number',
              bool: 'true or false', type(None): 'null'}


class Entry(NamedTuple):
  """A cell of an export: its line (references resolved), where its record and its evaluation were read (for
  messages), and the export that holds it."""
  line: dict
  where: Dict[str, str]
  export: str


def read_json(path: str) -> dict:
  """A JSON record (cell.json, metrics.json) as a dict; ValueError naming the file when it is not one."""
  try:
    with open(path) as f:
      record = json.load(f)
  except (UnicodeDecodeError, json.JSONDecodeError) as e:
    raise ValueError(f'{path}: not valid JSON ({e}); expected the record lab.study wrote (a merge conflict? '
                     'keep one side, or delete the cell\'s folder to run it again)') from None
  if not isinstance(record, dict):
    raise ValueError(f'{path}: a JSON {type(record).__name__}; expected the record (an object) lab.study wrote')
  return record


def _number(text: str):
  """A CSV cell as written: '' -> None, an integer literal -> int, else float."""
  if text == '':
    return None
  try:
    return int(text)
  except ValueError:
    return float(text)


def table(text: str) -> dict:
  """A CSV of numbers as {"columns": [...], "rows": [[...], ...]} (empty cells None)."""
  columns, *rows = list(csv.reader(io.StringIO(text, newline='')))
  return {'columns': columns, 'rows': [[_number(v) for v in row] for row in rows]}


def csv_text(columns: list, rows: list) -> str:
  """The CSV that csv.DictWriter writes for these columns and rows (None as an empty cell)."""
  text = io.StringIO()
  writer = csv.writer(text)
  writer.writerow(columns)
  writer.writerows(['' if v is None else v for v in row] for row in rows)
  return text.getvalue()


def line(cell_id: str, record: dict, evaluation: Optional[dict], curve_csv: Optional[str],
         spec: Optional[dict] = None, evaluations: Optional[dict] = None) -> dict:
  """A cell's line from its record, its evaluation's metrics.json (None: not kept), its learning curve's CSV and
  its further evaluations ({name: {'bindings', 'evaluation'}}; none: left out)."""
  entry = {'cell': cell_id}
  if spec is not None:
    entry['spec'] = spec
  entry['record'] = record
  if evaluation is not None:
    entry['evaluation'] = evaluation
  if curve_csv is not None:
    entry['learning_curve'] = table(curve_csv)
  if evaluations:
    entry['evaluations'] = evaluations
  return entry


def files(entry: dict) -> Dict[str, str]:
  """{file name: text} that a run leaves for the cell: cell.json, metrics.json, metrics.csv, learning_curve.csv."""
  texts = {CELL_FILE: json.dumps(entry['record'], indent=1)}
  evaluation = entry.get('evaluation')
  if evaluation is not None:
    texts[METRICS_FILE] = json.dumps(evaluation, indent=1)
    per_image = evaluation.get('per_image') or []
    if per_image:
      columns = list(per_image[0])
      texts[METRICS_TABLE] = csv_text(columns, [[view.get(c) for c in columns] for view in per_image])
  if 'learning_curve' in entry:
    texts[CURVE_FILE] = csv_text(entry['learning_curve']['columns'], entry['learning_curve']['rows'])
  return texts


def read(export_dir: str) -> Dict[str, Entry]:
  """{cell id: Entry} of an export's cells.jsonl, references resolved; ValueError naming the folder without one."""
  path = os.path.join(export_dir, CELLS_FILE)
  if not os.path.isfile(path):
    raise ValueError(f'{export_dir}: no {CELLS_FILE}; expected a folder that lab.study --export wrote')
  return {entry['cell']: _entry(export_dir, entry, where, ()) for entry, where in _lines(path)}


def _lines(path: str):
  """(line, 'FILE line N') of each line of a cells.jsonl, checked (_parse_line)."""
  with open(path) as f:
    for number, text in enumerate(f, 1):
      where = f'{path} line {number}'
      yield _parse_line(text, where), where


def _entry(export_dir: str, entry: dict, where: str, referrers: tuple) -> Entry:
  """The Entry of a line of export_dir's cells.jsonl: the line itself, or the line its reference leads to.
  referrers: the exports (real paths) whose lines for this cell led here, so that a loop is an error."""
  if 'same_as' not in entry:
    return Entry(entry, {k: f'{where} ("{k}")' for k in ('record', 'evaluation')}, export_dir)
  other = os.path.normpath(os.path.join(export_dir, entry['same_as']))
  chain = referrers + (os.path.realpath(export_dir),)
  if os.path.realpath(other) in chain:
    raise ValueError(f'{where}: cell {entry["cell"]} is the same as in {other}, which leads back here (a loop of '
                     'references); expected the export the cell was taken from')
  found = _cell_entry(other, entry['cell'], chain) if os.path.isdir(other) else None
  if found is None:
    raise ValueError(f'{where}: cell {entry["cell"]} is the same as in {other}, which does not hold it; expected '
                     'the export it was taken from beside this one')
  return found


def _cell_entry(export_dir: str, cell_id: str, referrers: tuple) -> Optional[Entry]:
  """The Entry of one cell of an export (its reference followed), None when the export does not hold it."""
  path = os.path.join(export_dir, CELLS_FILE)
  if not os.path.isfile(path):
    return None
  return next((_entry(export_dir, entry, where, referrers) for entry, where in _lines(path)
               if entry['cell'] == cell_id), None)


def _parse_line(text: str, where: str) -> dict:
  """One line of cells.jsonl; ValueError naming it when it is not a cell's line."""
  try:
    entry = json.loads(text)
  except json.JSONDecodeError as e:
    raise ValueError(f'{where}: not valid JSON ({e}); expected one cell\'s line as lab.study wrote it (a merge '
                     'conflict? keep one side of each conflicting line)') from None
  if not isinstance(entry, dict) or 'cell' not in entry or not ({'record', 'same_as'} & set(entry)):
    raise ValueError(f'{where}: expected an object with "cell" and "record" (or "same_as"), as lab.study writes')
  for key, kind in LINE_TYPES.items():
    if key in entry and not isinstance(entry[key], kind):
      raise ValueError(f'{where}: "{key}" is {JSON_NAMES[type(entry[key])]}; expected {JSON_NAMES[kind]}, as '
                       'lab.study writes')
  return entry


def write(export_dir: str, lines: List[dict]) -> str:
  """Writes export_dir/cells.jsonl, a line per cell; returns its path."""
  path = os.path.join(export_dir, CELLS_FILE)
  atomic.write_text(path, ''.join(json.dumps(entry) + '\n' for entry in lines))
  return path


def same_cell(a: dict, b: dict) -> bool:
  """Whether two lines hold the same run: record, evaluations and learning curve (the spec may be spelt apart)."""
  keys = ('record', 'evaluation', 'learning_curve', 'evaluations')
  return all(json.dumps(a.get(k), sort_keys=True) == json.dumps(b.get(k), sort_keys=True) for k in keys)


def reference(export_dir: str, entry: dict, other_export: str) -> Optional[dict]:
  """A reference line to other_export (relative to export_dir) when it holds the same run of the cell, else None."""
  found = _cell_entry(other_export, entry['cell'], ())
  if found is None or not same_cell(found.line, entry):
    return None
  return {'cell': entry['cell'], 'same_as': os.path.relpath(found.export, export_dir)}


def spec(study, cell) -> dict:
  """A cell's gin configs and bindings with {out} and {data_root} left as templates (no machine's paths)."""
  from lab.study import spec as study_spec  # pylint: disable=import-outside-toplevel
  run_dir = f'{{out}}/{study.name}/{cell.cell_id}/run'
  configs, bindings = study_spec.cell_gin(study, cell, '{out}', '{data_root}', run_dir)
  return {'gin_configs': configs, 'gin_bindings': bindings}
