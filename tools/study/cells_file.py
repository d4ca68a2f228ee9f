"""An export's cells in one file, cells.jsonl: a line per finished cell with what it ran, what it measured and
where; a cell that came from another study's export is a reference to that export's line, not a copy.

A line is {"cell": id, "spec": {"gin_configs", "gin_bindings"} (templates {out} and {data_root} left in),
"record": the cell's cell.json (means, wall times, steps/s, GFLOP per step, peak memory, commit, changed files,
machine), "evaluation": its metrics.json (per view and means; metrics.csv is its per_image as a table),
"learning_curve": {"columns", "rows"} where the run recorded one}; or {"cell": id, "same_as": "../other_export"}.

Exports written before this file kept a folder per cell (<cell>/cell.json, metrics.json, metrics.csv,
learning_curve.csv) and the cells' commits again in provenance.json. `read` takes either layout, and

  python -m tools.study.cells_file DIR [DIR ...]

converts old ones in place (a folder already converted is left as it is): it writes cells.jsonl and removes the
cell folders only once every file of every folder comes back byte for byte from its line (`files`), else it stops
with one line naming the first file that would not, having changed nothing. A cell folder that is a link or holds a
folder, and an export it cannot change (a read-only file system, an immutable folder), are one line each too, the
export left as it was.
"""

import argparse
import csv
import errno
import io
import json
import os
import shutil
import sys
from typing import Dict, List, NamedTuple, Optional

from internal import atomic
from internal import cli

CELLS_FILE = 'cells.jsonl'
CELL_FILE = 'cell.json'
METRICS_FILE = 'metrics.json'
METRICS_TABLE = 'metrics.csv'
CURVE_FILE = 'learning_curve.csv'  # internal/evaluation/learning_curve.py's CSV_FILE (jax-free here).
PROVENANCE_FILE = 'provenance.json'
CONVERTING = '.cells_file.converting'  # The old cell folders during a conversion (deleted at its end).
# The parts of a line and the JSON type each must have.
LINE_TYPES = {'cell': str, 'same_as': str, 'spec': dict, 'record': dict, 'evaluation': dict, 'learning_curve': dict}
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
    raise ValueError(f'{path}: not valid JSON ({e}); expected the record tools.study wrote (a merge conflict? '
                     'keep one side, or delete the cell\'s folder to run it again)') from None
  if not isinstance(record, dict):
    raise ValueError(f'{path}: a JSON {type(record).__name__}; expected the record (an object) tools.study wrote')
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
         spec: Optional[dict] = None) -> dict:
  """A cell's line from its record, its evaluation's metrics.json (None: not kept) and its learning curve's CSV."""
  entry = {'cell': cell_id}
  if spec is not None:
    entry['spec'] = spec
  entry['record'] = record
  if evaluation is not None:
    entry['evaluation'] = evaluation
  if curve_csv is not None:
    entry['learning_curve'] = table(curve_csv)
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
  """{cell id: Entry} of an export in either layout (cells.jsonl, or a folder per cell), references resolved."""
  path = os.path.join(export_dir, CELLS_FILE)
  if not os.path.isfile(path):
    folders = [n for n in sorted(os.listdir(export_dir)) if os.path.isfile(os.path.join(export_dir, n, CELL_FILE))]
    return {n: _folder_entry(export_dir, n) for n in folders}
  return {entry['cell']: _entry(export_dir, entry, where, ()) for entry, where in _lines(path)}


def _lines(path: str):
  """(line, 'FILE line N') of each line of a cells.jsonl, checked (_parse_line)."""
  with open(path) as f:
    for number, text in enumerate(f, 1):
      where = f'{path} line {number}'
      yield _parse_line(text, where), where


def _folder_entry(export_dir: str, cell_id: str) -> Entry:
  """The Entry of an old-layout export's cell folder."""
  folder = os.path.join(export_dir, cell_id)
  return Entry(_folder_line(folder), {'record': os.path.join(folder, CELL_FILE),
                                      'evaluation': os.path.join(folder, METRICS_FILE)}, export_dir)


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
    return _folder_entry(export_dir, cell_id) if os.path.isfile(os.path.join(export_dir, cell_id, CELL_FILE)) else None
  return next((_entry(export_dir, entry, where, referrers) for entry, where in _lines(path)
               if entry['cell'] == cell_id), None)


def _parse_line(text: str, where: str) -> dict:
  """One line of cells.jsonl; ValueError naming it when it is not a cell's line."""
  try:
    entry = json.loads(text)
  except json.JSONDecodeError as e:
    raise ValueError(f'{where}: not valid JSON ({e}); expected one cell\'s line as tools.study wrote it (a merge '
                     'conflict? keep one side of each conflicting line)') from None
  if not isinstance(entry, dict) or 'cell' not in entry or not ({'record', 'same_as'} & set(entry)):
    raise ValueError(f'{where}: expected an object with "cell" and "record" (or "same_as"), as tools.study writes')
  for key, kind in LINE_TYPES.items():
    if key in entry and not isinstance(entry[key], kind):
      raise ValueError(f'{where}: "{key}" is {JSON_NAMES[type(entry[key])]}; expected {JSON_NAMES[kind]}, as '
                       'tools.study writes')
  return entry


def _folder_line(folder: str) -> dict:
  """A cell's line from an old-layout export's folder (cell.json, metrics.json, learning_curve.csv)."""
  record = read_json(os.path.join(folder, CELL_FILE))
  metrics = os.path.join(folder, METRICS_FILE)
  curve = os.path.join(folder, CURVE_FILE)
  curve_csv = None
  if os.path.isfile(curve):
    with open(curve, newline='') as f:
      curve_csv = f.read()
  return line(os.path.basename(folder), record, read_json(metrics) if os.path.isfile(metrics) else None, curve_csv)


def write(export_dir: str, lines: List[dict]) -> str:
  """Writes export_dir/cells.jsonl, a line per cell; returns its path."""
  path = os.path.join(export_dir, CELLS_FILE)
  atomic.write_text(path, ''.join(json.dumps(entry) + '\n' for entry in lines))
  return path


def same_cell(a: dict, b: dict) -> bool:
  """Whether two lines hold the same run: record, evaluation and learning curve (the spec may be spelt apart)."""
  keys = ('record', 'evaluation', 'learning_curve')
  return all(json.dumps(a.get(k), sort_keys=True) == json.dumps(b.get(k), sort_keys=True) for k in keys)


def reference(export_dir: str, entry: dict, other_export: str) -> Optional[dict]:
  """A reference line to other_export (relative to export_dir) when it holds the same run of the cell, else None."""
  found = read(other_export).get(entry['cell']) if os.path.isdir(other_export) else None
  if found is None or not same_cell(found.line, entry):
    return None
  return {'cell': entry['cell'], 'same_as': os.path.relpath(found.export, export_dir)}


# ------------------------------------------------------------------ converting an old layout


def convert(export_dir: str, spec_of=None) -> Optional[dict]:
  """Converts an old-layout export in place; returns {'cells', 'references', 'removed'} (None: converted before).

  spec_of(cell id) gives a cell's spec (None where unknown). A cell whose record names another study is a reference
  when the export of that study beside this one holds the same run. ValueError naming the first file that its
  line would not give back byte for byte, a cell folder that is a link or holds a folder, a provenance.json entry
  that disagrees with its cell's record, or what could not be written; nothing is changed then.
  """
  if os.path.isfile(os.path.join(export_dir, CELLS_FILE)):
    return None
  provenance_path = os.path.join(export_dir, PROVENANCE_FILE)
  if not os.path.isfile(provenance_path):
    raise ValueError(f'{export_dir}: no {PROVENANCE_FILE}; expected a folder that tools.study --export wrote')
  provenance = read_json(provenance_path)
  entries = read(export_dir)
  for cell_id, entry in entries.items():
    _check_round_trip(os.path.join(export_dir, cell_id), entry.line)
    _check_provenance(provenance, provenance_path, entry.line)
  lines = [_converted_line(export_dir, entry.line, spec_of) for entry in entries.values()]
  provenance.pop('cells', None)
  removed = sum(len(os.listdir(os.path.join(export_dir, cell_id))) for cell_id in entries)
  _replace_folders(export_dir, lines, provenance, list(entries))
  return {'cells': len(lines), 'references': sum('same_as' in l for l in lines), 'removed': removed}


def _replace_folders(export_dir: str, lines: List[dict], provenance: dict, cell_ids: List[str]) -> None:
  """Writes cells.jsonl, moves the cell folders into a hidden folder, writes provenance.json, then deletes the
  hidden folder. A step that fails (a read-only file system, an immutable folder) undoes the ones before it: a
  ValueError naming what could not be written, the export as it was (a full disk stays an OSError, undone too)."""
  aside = os.path.join(export_dir, CONVERTING)
  done = []  # Undo steps, newest last.
  try:
    write(export_dir, lines)
    done.append(lambda: os.remove(os.path.join(export_dir, CELLS_FILE)))
    os.mkdir(aside)
    done.append(lambda: os.rmdir(aside))
    for cell_id in cell_ids:
      os.rename(os.path.join(export_dir, cell_id), os.path.join(aside, cell_id))
      done.append(lambda c=cell_id: os.rename(os.path.join(aside, c), os.path.join(export_dir, c)))
    atomic.write_text(os.path.join(export_dir, PROVENANCE_FILE), json.dumps(provenance, indent=1))
  except OSError as err:
    for undo in reversed(done):
      undo()
    if err.errno == errno.ENOSPC:
      raise
    raise ValueError(f'{export_dir}: cannot be converted: {err.strerror} ({err.filename!r}); expected an export '
                     'whose folder and cell folders can be changed (nothing was converted)') from None
  try:
    shutil.rmtree(aside)
  except OSError as err:
    raise ValueError(f'{export_dir}: converted, but {aside}, its old cell folders (each file in {CELLS_FILE} byte '
                     f'for byte), could not be deleted: {err.strerror} ({err.filename!r}); delete it by hand') from None


def _converted_line(export_dir: str, entry: dict, spec_of) -> dict:
  """The line an old-layout cell becomes: a reference to the export of the study its record names, when that
  export (a folder of that name beside this one) holds the same run; else the whole line with its spec."""
  study = entry['record'].get('study')
  if study and study != os.path.basename(os.path.normpath(export_dir)):
    found = reference(export_dir, entry, os.path.join(os.path.dirname(os.path.normpath(export_dir)), study))
    if found is not None:
      return found
  spec = spec_of(entry['cell']) if spec_of else None
  return line(entry['cell'], entry['record'], entry.get('evaluation'),
              files(entry).get(CURVE_FILE), spec)


def _check_round_trip(folder: str, entry: dict) -> None:
  """ValueError naming an old cell folder that is a link, or the first thing in it that the cell's line does not
  give back byte for byte (a file, or a folder)."""
  if os.path.islink(folder):
    raise ValueError(f'{folder}: a symbolic link (to {os.readlink(folder)}); expected the cell folder that '
                     'tools.study --export wrote: put a copy of that folder in its place (nothing was converted)')
  texts = files(entry)
  for name in sorted(os.listdir(folder)):
    if os.path.isdir(os.path.join(folder, name)):
      raise ValueError(f'{os.path.join(folder, name)}: a folder, which {CELLS_FILE} cannot hold; expected only '
                       'cell.json, metrics.json, metrics.csv and learning_curve.csv as tools.study wrote them: move '
                       'it out of the export (nothing was converted)')
    with open(os.path.join(folder, name), newline='') as f:
      if texts.get(name) != f.read():
        raise ValueError(f'{os.path.join(folder, name)}: its line in {CELLS_FILE} would not give it back byte for '
                         'byte; expected only cell.json, metrics.json, metrics.csv and learning_curve.csv as '
                         'tools.study wrote them (nothing was converted)')


def _check_provenance(provenance: dict, path: str, entry: dict) -> None:
  """ValueError when provenance.json's entry for the cell (commit, changed files, machine, seconds, step: a copy
  of fields of its cell.json, dropped in the conversion) says other than the cell's record."""
  kept = (provenance.get('cells') or {}).get(entry['cell'])
  if kept is not None and kept != {k: entry['record'].get(k) for k in kept}:
    raise ValueError(f'{path}: its entry for {entry["cell"]} differs from that cell\'s {CELL_FILE}; expected the '
                     'copy the export wrote (nothing was converted)')


def _spec_reader(export_dir: str):
  """spec_of(cell id) for an export: the cell's gin from the study file its provenance.json names (templates
  left in), or None for every cell when that file is not in this checkout or its git history."""
  from tools.study import reuse  # pylint: disable=import-outside-toplevel  (reuse reads exports through this file)
  from tools.study import spec as study_spec  # pylint: disable=import-outside-toplevel
  try:
    study = reuse.exported_study(export_dir)
  except study_spec.StudyError:
    return None
  cells = {c.cell_id: c for c in study_spec.cells(study)}
  return lambda cell_id: spec(study, cells[cell_id]) if cell_id in cells else None


def spec(study, cell) -> dict:
  """A cell's gin configs and bindings with {out} and {data_root} left as templates (no machine's paths)."""
  from tools.study import spec as study_spec  # pylint: disable=import-outside-toplevel
  run_dir = f'{{out}}/{study.name}/{cell.cell_id}/run'
  configs, bindings = study_spec.cell_gin(study, cell, '{out}', '{data_root}', run_dir)
  return {'gin_configs': configs, 'gin_bindings': bindings}


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(prog='python -m tools.study.cells_file', description=__doc__.split('\n\n')[0])
  parser.add_argument('exports', nargs='+', metavar='DIR', help='folders that tools.study --export wrote')
  for export_dir in parser.parse_args(argv).exports:
    done = convert(export_dir, _spec_reader(export_dir))
    if done is None:
      print(f'{export_dir}: has {CELLS_FILE} already; left as it is')
    else:
      print(f'{export_dir}: {done["cells"]} cells into {CELLS_FILE} ({done["references"]} references to other '
            f'exports), {done["removed"]} files of cell folders removed')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
