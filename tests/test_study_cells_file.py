"""An export's cells in one file (lab/study/cells_file.py): a line per cell or a reference to another export's line,
read back with one line naming what is wrong; and every export committed under results/ is in that layout."""

import hashlib
import json
import pathlib
import re

import pytest

from internal import cli
from test_study import TINY_STUDY
from lab.study import cells_file
from lab.study import reuse
from lab.study import runner as study_lib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_a_conflicted_line_or_a_dangling_reference_is_one_error_naming_the_line(tmp_path):
  (tmp_path / 'cells.jsonl').write_text('{"cell": "a", "record": {}}\n<<<<<<< HEAD\n')
  with pytest.raises(ValueError, match=r'cells.jsonl line 2: not valid JSON'):
    cells_file.read(str(tmp_path))
  (tmp_path / 'cells.jsonl').write_text('{"cell": "a", "same_as": "../gone"}\n')
  with pytest.raises(ValueError, match=r'cells.jsonl line 1: cell a is the same as in .*gone, which does not hold'):
    cells_file.read(str(tmp_path))


def test_a_folder_without_cells_jsonl_is_one_error_naming_it(tmp_path):
  """The layout of a folder per cell is gone (no export under results/ kept it): such a folder is no export."""
  (tmp_path / 'a__cup__seed=0').mkdir()
  (tmp_path / 'a__cup__seed=0' / 'cell.json').write_text('{}')
  with pytest.raises(ValueError, match=re.escape(f'{tmp_path}: no cells.jsonl; expected a folder that lab.study '
                                                 '--export wrote')):
    cells_file.read(str(tmp_path))


def _exports():
  """The folders under results/ that lab.study --export wrote (they hold provenance.json and a results.csv)."""
  return sorted(p.parent for p in (ROOT / 'results').rglob('provenance.json') if (p.parent / 'results.csv').is_file())


@pytest.mark.parametrize('export', _exports(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_committed_export_holds_its_cells_in_one_file(export):
  assert (export / 'cells.jsonl').is_file() and not [p for p in export.iterdir() if (p / 'cell.json').is_file()]
  entries = cells_file.read(str(export))
  assert entries and all(reuse.checked(e) for e in entries.values())    # Each record agrees with its evaluation.
  assert 'cells' not in json.loads((export / 'provenance.json').read_text())
  studies = ROOT / 'results' / 'studies'  # Each study folder has its README; cpu-mini's exports share their parent's.
  readme = export / 'README.md' if export.parent == studies else export.parent / 'README.md'
  assert readme.is_file(), f'{export} has no README.md'
  dirty = [c for c, e in entries.items() if (e.line['record'].get('commit') or '').endswith('+dirty')]
  assert not dirty or 'uncommitted changes' in readme.read_text(), (
      f'{readme} does not say that {len(dirty)} cells ran from a tree with uncommitted changes: {dirty[:3]}')


@pytest.mark.parametrize('text, message', [
    ('{"cell": "a", "record": "done"}', '{export}/cells.jsonl line 1: "record" is a string; expected an object'),
    ('{"cell": "a", "record": {}, "evaluation": [1]}',
     '{export}/cells.jsonl line 1: "evaluation" is an array; expected an object'),
    ('{"cell": 3, "record": {}}', '{export}/cells.jsonl line 1: "cell" is a number; expected a string'),
    ('{"cell": "a", "same_as": "."}', '{export}/cells.jsonl line 1: cell a is the same as in {export}, which leads back '
                                      'here (a loop of references)'),
    ('{"cell": "a", "same_as": "../other"}', '{other}/cells.jsonl line 2: cell a is the same as in {export}, which '
                                             'leads back here'),
])
def test_a_line_of_the_wrong_shape_or_a_loop_of_references_is_one_line_naming_it(tmp_path, capsys, text, message):
  export, other = tmp_path / 'export', tmp_path / 'other'
  export.mkdir()
  other.mkdir()
  (export / 'cells.jsonl').write_text(text + '\n')
  (other / 'cells.jsonl').write_text('{"cell": "b", "record": {}}\n{"cell": "a", "same_as": "../export"}\n')
  message = message.format(export=export, other=other)
  with pytest.raises(ValueError, match=re.escape(message)):
    cells_file.read(str(export))
  study = tmp_path / 'mini.toml'
  study.write_text(TINY_STUDY)
  (export / 'provenance.json').write_text(json.dumps({'study_file': {
      'path': str(study), 'sha256': hashlib.sha256(TINY_STUDY.encode()).hexdigest()}}))
  status = cli.run(lambda: study_lib.main([str(study), '--out', str(tmp_path / 'out'), '--reuse', str(export),
                                           '--list']))
  err = capsys.readouterr().err
  assert status == cli.USAGE_ERROR_STATUS and err == f'error: {message}' + err.split(message, 1)[1], err
  assert len(err.strip().splitlines()) == 1


def test_references_between_two_exports_each_way_are_no_loop(tmp_path):
  """Export a took cell x from b, and b took cell y from a: each line leads to a line with the record."""
  (tmp_path / 'a').mkdir()
  (tmp_path / 'b').mkdir()
  (tmp_path / 'a' / 'cells.jsonl').write_text('{"cell": "x", "same_as": "../b"}\n{"cell": "y", "record": {"n": 1}}\n')
  (tmp_path / 'b' / 'cells.jsonl').write_text('{"cell": "x", "record": {"n": 2}}\n{"cell": "y", "same_as": "../a"}\n')
  for export in ('a', 'b'):
    entries = cells_file.read(str(tmp_path / export))
    assert {c: e.line['record']['n'] for c, e in entries.items()} == {'x': 2, 'y': 1}
