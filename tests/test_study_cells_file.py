"""An export's cells in one file (tools/study/cells_file.py): the conversion from a folder per cell loses nothing (every
file comes back byte for byte), refuses what it could not give back, refers to another study's export instead of
copying its cell; and every export committed under results/ is in that layout."""

import contextlib
import hashlib
import json
import pathlib
import re
import subprocess

import pytest

from internal import cli
from internal.evaluation import evaluate
from internal.evaluation import learning_curve
from test_read_only import read_only
from test_study import TINY_STUDY
from tools.study import cells_file
from tools.study import reuse
from tools.study import runner as study_lib

ROOT = pathlib.Path(__file__).resolve().parents[1]
PER_IMAGE = [{'id': 1, 'psnr': 10.251645574334333, 'ssim': 0.1712803298432899, 'lpips': None},
             {'id': 9, 'psnr': 9.35178155515592, 'ssim': 0.26158671394948524, 'lpips': None}]


def _cell(export: pathlib.Path, cell: str, study: str, psnr_shift: float = 0., curve: bool = True) -> dict:
  """Writes an old-layout cell folder as tools.study --export wrote it (cell.json, metrics.json, metrics.csv,
  learning_curve.csv); returns its cell.json record."""
  folder = export / cell
  folder.mkdir(parents=True)
  per_image = [{**v, 'psnr': v['psnr'] + psnr_shift} for v in PER_IMAGE]
  means = {'psnr': sum(v['psnr'] for v in per_image) / 2, 'ssim': 0.2164335220805376, 'lpips': None}
  record = {'study': study, 'cell': cell, 'step': 20, 'complete': False, 'means': means, 'train_seconds': 225.8,
            'commit': '62ae429259271f55befceee49f6bccc220e5fbb6', 'machine': {'cpu_count': 2}}
  (folder / 'cell.json').write_text(json.dumps(record, indent=1))
  metrics = {'dataset': 'dtu', 'step': 20, 'means': means, 'per_image': per_image, 'complete': False,
             'seeds': [0, 0], 'run_dir': f'/elsewhere/{cell}/run'}
  (folder / 'metrics.json').write_text(json.dumps(metrics, indent=1))
  evaluate.write_csv(per_image, str(folder / 'metrics.csv'))
  if curve:
    log = learning_curve.CurveLog(str(folder), 0)
    log.append({'step': 10, 'psnr': 10.328888547097533, 'psnr_masked': None, 'seconds': 10.914614100998733})
    log.append({'step': 20, 'psnr': 1e-05, 'psnr_masked': 9.5, 'seconds': 18.940542452000955})
  return record


def _export(path: pathlib.Path, study: str, cells: dict) -> pathlib.Path:
  """An old-layout export of study at path: {cell id: (study its record names, psnr shift)}, provenance.json with
  the per-cell copies the old exports kept."""
  records = {cell: _cell(path, cell, owner, shift, curve=i == 0)
             for i, (cell, (owner, shift)) in enumerate(cells.items())}
  provenance = {'command': 'python -m tools.study x.toml --export x', 'study_file': {'path': 'x', 'sha256': 'ab'},
                'cells': {c: {k: r.get(k) for k in ('commit', 'machine', 'train_seconds', 'step')}
                          for c, r in records.items()}}
  (path / 'provenance.json').write_text(json.dumps(provenance, indent=1))
  (path / 'results.csv').write_text('cell,psnr\n')
  return path


def _snapshot(folder: pathlib.Path) -> dict:
  """{relative path: bytes} of every file under folder."""
  return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob('*')) if p.is_file()}


def test_the_conversion_gives_back_every_file_byte_for_byte(tmp_path):
  export = _export(tmp_path / 'cup', 'cup', {'a__cup__seed=0': ('cup', 0.), 'b__cup__seed=0': ('cup', 1.)})
  before = _snapshot(export)
  assert cells_file.convert(str(export)) == {'cells': 2, 'references': 0, 'removed': 7}
  assert sorted(p.name for p in export.iterdir()) == ['cells.jsonl', 'provenance.json', 'results.csv']
  entries = cells_file.read(str(export))
  for cell, entry in entries.items():
    for name, text in cells_file.files(entry.line).items():
      assert text.encode() == before[f'{cell}/{name}'], (cell, name)
    assert {f'{cell}/{name}' for name in cells_file.files(entry.line)} == {k for k in before if k.startswith(cell)}
  provenance = json.loads((export / 'provenance.json').read_text())
  old = json.loads(before['provenance.json'])
  assert provenance == {k: v for k, v in old.items() if k != 'cells'} and (export / 'results.csv').read_bytes() == \
      before['results.csv']
  assert cells_file.convert(str(export)) is None                        # Converted once: left as it is.


def test_a_cell_from_another_studys_export_is_a_reference_to_it(tmp_path):
  _export(tmp_path / 'cup', 'cup', {'a__cup__seed=0': ('cup', 0.), 'b__cup__seed=0': ('cup', 0.)})
  regnerf = _export(tmp_path / 'regnerf', 'regnerf', {'a__cup__seed=0': ('cup', 0.),      # The same run: referred to.
                                                      'b__cup__seed=0': ('cup', 2.),      # Another: kept whole.
                                                      'c__cup__seed=0': ('regnerf', 0.)})
  before = _snapshot(regnerf)
  assert cells_file.convert(str(regnerf))['references'] == 1
  lines = [json.loads(l) for l in (regnerf / 'cells.jsonl').read_text().splitlines()]
  assert lines[0] == {'cell': 'a__cup__seed=0', 'same_as': '../cup'} and 'record' in lines[1]
  cells_file.convert(str(tmp_path / 'cup'))                             # The referred export converted too.
  for cell, entry in cells_file.read(str(regnerf)).items():
    for name, text in cells_file.files(entry.line).items():
      assert text.encode() == before[f'{cell}/{name}']
  assert cells_file.read(str(regnerf))['a__cup__seed=0'].export == str(tmp_path / 'cup')


@pytest.mark.parametrize('spoil, message', [
    (lambda cell: (cell / 'notes.txt').write_text('x'), 'notes.txt: its line in cells.jsonl would not give it back'),
    (lambda cell: (cell / 'metrics.csv').write_text('id,psnr\n1,10.25\n'), 'metrics.csv: its line in cells.jsonl'),
    (lambda cell: (cell / 'cell.json').write_text((cell / 'cell.json').read_text().replace('\n', '\n ')),
     'cell.json: its line in cells.jsonl'),
])
def test_a_file_its_line_cannot_give_back_stops_the_conversion_unchanged(tmp_path, spoil, message):
  export = _export(tmp_path / 'cup', 'cup', {'a__cup__seed=0': ('cup', 0.)})
  spoil(export / 'a__cup__seed=0')
  before = _snapshot(export)
  with pytest.raises(ValueError, match=message):
    cells_file.convert(str(export))
  assert _snapshot(export) == before


def test_a_provenance_copy_that_disagrees_with_its_cell_stops_the_conversion(tmp_path):
  export = _export(tmp_path / 'cup', 'cup', {'a__cup__seed=0': ('cup', 0.)})
  provenance = json.loads((export / 'provenance.json').read_text())
  provenance['cells']['a__cup__seed=0']['train_seconds'] = 1.
  (export / 'provenance.json').write_text(json.dumps(provenance))
  with pytest.raises(ValueError, match='its entry for a__cup__seed=0 differs from that cell'):
    cells_file.convert(str(export))
  assert (export / 'a__cup__seed=0' / 'cell.json').is_file() and not (export / 'cells.jsonl').exists()


def test_a_conflicted_line_or_a_dangling_reference_is_one_error_naming_the_line(tmp_path):
  (tmp_path / 'cells.jsonl').write_text('{"cell": "a", "record": {}}\n<<<<<<< HEAD\n')
  with pytest.raises(ValueError, match=r'cells.jsonl line 2: not valid JSON'):
    cells_file.read(str(tmp_path))
  (tmp_path / 'cells.jsonl').write_text('{"cell": "a", "same_as": "../gone"}\n')
  with pytest.raises(ValueError, match=r'cells.jsonl line 1: cell a is the same as in .*gone, which does not hold'):
    cells_file.read(str(tmp_path))


def _exports():
  """The folders under results/ that tools.study --export wrote (they hold provenance.json and a results.csv)."""
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


def _convert_one_line(capsys, export) -> str:
  """The stderr line of `python -m tools.study.cells_file export` as the module runs it; asserts status 2 and one
  line."""
  status = cli.run(lambda: cells_file.main([str(export)]))
  err = capsys.readouterr().err
  assert status == cli.USAGE_ERROR_STATUS and len(err.strip().splitlines()) == 1 and err.startswith('error: '), err
  return err


@contextlib.contextmanager
def _immutable(folder):
  """folder immutable (chattr +i: not even root changes it) for the block; skips where the file system has no such
  attribute."""
  made = subprocess.run(['chattr', '+i', str(folder)], capture_output=True, text=True, check=False)
  if made.returncode:
    pytest.skip(f'chattr +i is not available here: {made.stderr.strip()}')
  try:
    yield
  finally:
    subprocess.run(['chattr', '-i', str(folder)], check=True)


@pytest.mark.parametrize('lock, expected', [
    (lambda export: read_only(export), 'Read-only file system'),
    (lambda export: _immutable(export / 'b__cup__seed=0'), 'Operation not permitted'),
])
def test_an_export_it_cannot_change_is_one_line_and_left_as_it_was(tmp_path, capsys, lock, expected):
  export = _export(tmp_path / 'cup', 'cup', {'a__cup__seed=0': ('cup', 0.), 'b__cup__seed=0': ('cup', 1.)})
  before = _snapshot(export)
  with lock(export):
    err = _convert_one_line(capsys, export)
  assert f'{export}: cannot be converted: {expected}' in err and '(nothing was converted)' in err
  assert _snapshot(export) == before and sorted(p.name for p in export.iterdir()) == sorted(
      ['a__cup__seed=0', 'b__cup__seed=0', 'provenance.json', 'results.csv'])


def _linked(export):
  """The cell folder moved beside the export, a symbolic link to it in its place."""
  (export / 'a__cup__seed=0').rename(export.parent / 'elsewhere')
  (export / 'a__cup__seed=0').symlink_to(export.parent / 'elsewhere')


@pytest.mark.parametrize('spoil, message', [
    (lambda export: (export / 'a__cup__seed=0' / 'plots').mkdir(), 'a__cup__seed=0/plots: a folder'),
    (_linked, 'a__cup__seed=0: a symbolic link'),
])
def test_a_cell_folder_with_a_folder_or_that_is_a_link_is_one_line_and_nothing_is_converted(tmp_path, capsys, spoil,
                                                                                            message):
  export = _export(tmp_path / 'cup', 'cup', {'a__cup__seed=0': ('cup', 0.)})
  spoil(export)
  before = _snapshot(export)
  err = _convert_one_line(capsys, export)
  assert message in err and '(nothing was converted)' in err
  assert _snapshot(export) == before and (export / 'a__cup__seed=0' / 'cell.json').is_file()


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
