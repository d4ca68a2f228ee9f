"""lab.study end to end on the generated scene (2 methods x 2 scenes, tiny): cells, CSV, plots, resume, tables;
and the study file's errors."""

import csv
import hashlib
import json
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
from PIL import Image
import pytest

from internal.evaluation import vis
from internal.pipeline import loop
from tools import provenance
from tools import tables
from lab.study import cells_file
from lab.study import export as study_export
from lab.study import plots as study_plots
from lab.study import runner as study_lib
from lab.study import spec as study_spec

REPO = pathlib.Path(__file__).resolve().parents[1]
STEPS = 20
TINY_STUDY = f'''
name = "mini"
bindings = ["MLP.net_depth = 2", "MLP.net_width = 16", "MLP.net_width_viewdirs = 16",
            "MipNerfModel.num_samples = 8", "Config.batch_size = 64", "Config.max_steps = {STEPS}",
            "Config.freq_reg_end = 18", "Config.print_every = 10", "Config.train_render_every = 0",
            "Config.checkpoint_every = 10", "Config.compute_lpips = False", "Config.render_chunk_size = 192",
            "Config.curve_every = 10", "Config.curve_factor = 1",
            "Config.generated_size = (12, 16)", "Config.data_dir = '{{out}}/scenes/{{scene}}'"]
[methods.freenerf]
configs = ["{REPO}/configs/demo.gin"]
[methods.mipnerf]
configs = ["{REPO}/configs/demo.gin"]
bindings = ["Config.freq_reg = False", "Config.freq_reg_end = 0", "Config.occ_reg_loss_mult = 0."]
[scenes.object]
bindings = ["Config.generated_rig = 'object'"]
[scenes.forward]
bindings = ["Config.generated_rig = 'forward'"]
[[axis]]
name = "views"
binding = "Config.n_input_views"
values = [3]
[plot]
x = ["views", "gflops_per_step"]
metrics = ["psnr", "depth_mae"]
pareto = true
[[paper]]
method = "freenerf"
metric = "psnr"
x = "views"
points = [[3, 10.0]]
'''


def _rows(path):
  with open(path, newline='') as f:
    return list(csv.DictReader(f))


@pytest.fixture(scope='module', name='ran')
def fixture_ran(tmp_path_factory):
  """(study, out) after a half-trained cell was started by hand and the study was run in-process."""
  out = str(tmp_path_factory.mktemp('study') / 'out')
  path = pathlib.Path(out).parent / 'mini.toml'
  path.write_text(TINY_STUDY)
  study = study_spec.load(path)
  half = study_lib.write_spec(study, study_spec.cells(study)[0], out, 'data')
  with study_spec.cell_config(half) as config:
    loop.train(config, stop_at_step=10)
  assert study_lib.run_study(study, out) == {}  # No executor: in this process.
  return study, out, path


def test_every_cell_is_recorded_with_metrics_and_costs(ran):
  study, out, _ = ran
  rows = _rows(os.path.join(out, 'mini', study_lib.RESULTS_FILE))
  assert [r['cell'] for r in rows] == ['freenerf__object__views=3', 'freenerf__forward__views=3',
                                       'mipnerf__object__views=3', 'mipnerf__forward__views=3']
  for row in rows:
    assert row['status'] == 'done' and row['step'] == str(STEPS) and row['complete'] == 'True'
    assert 5. < float(row['psnr']) < 40. and float(row['depth_mae']) > 0.
    assert 0. <= float(row['depth_within_5pct']) <= 1. and float(row['gflops_per_step']) > 0.
    assert float(row['train_seconds']) > 0. and float(row['peak_rss_mb']) > 100.
  assert [r['steps_trained'] for r in rows] == ['10', '20', '20', '20']     # The half-done cell resumed.
  first = study_lib.read_cell(os.path.join(out, 'mini', rows[0]['cell']))
  assert first['resumed_from_step'] == 10 and first['expname'] == 'freenerf'


def test_plots_are_png_images(ran):
  _, out, _ = ran
  for name in ('psnr_vs_views', 'depth_mae_vs_views', 'psnr_vs_gflops_per_step'):
    with Image.open(os.path.join(out, 'mini', f'{name}.png')) as image:
      assert image.format == 'PNG' and image.size == (640, 440)


def test_learning_curves_are_plotted_against_the_step(ran):
  study, out, _ = ran
  for cell in study_spec.cells(study):         # The half-trained cell too: no row lost or repeated on resuming.
    rows = _rows(os.path.join(out, 'mini', cell.cell_id, study_lib.RUN_SUBDIR, 'learning_curve.csv'))
    assert [r['step'] for r in rows] == ['10', '20'] and float(rows[1]['seconds']) > float(rows[0]['seconds'])
  curves = study_lib.gather_curves(study, out)
  assert len(curves) == 8 and {c['method'] for c in curves} == {'freenerf', 'mipnerf'}
  assert all(c['views'] == '3' for c in curves)
  lines = study_plots._series(study, curves, 'step', 'psnr', None)  # pylint: disable=protected-access
  assert sorted(lines) == ['freenerf forward views=3', 'freenerf object views=3', 'mipnerf forward views=3',
                           'mipnerf object views=3']
  assert all([x for x, _ in points] == [10., 20.] for points in lines.values())
  with Image.open(os.path.join(out, 'mini', 'psnr_vs_step.png')) as image:
    assert image.format == 'PNG' and image.size == (640, 440)
  assert not os.path.exists(os.path.join(out, 'mini', 'psnr_masked_vs_step.png'))   # No DTU masks here.


def test_rerun_skips_finished_cells(ran):
  _, out, path = ran
  before = {p: p.read_text() for p in pathlib.Path(out, 'mini').glob(f'*/{study_lib.CELL_FILE}')}
  result = subprocess.run([sys.executable, '-m', 'lab.study', str(path), '--out', out], cwd=REPO,
                          capture_output=True, text=True, check=True)
  assert 'running' not in result.stdout and 'results.csv' in result.stdout
  assert len(before) == 4 and all(p.read_text() == text for p, text in before.items())
  listing = subprocess.run([sys.executable, '-m', 'lab.study', str(path), '--out', out, '--list'], cwd=REPO,
                           capture_output=True, text=True, check=True).stdout
  assert listing.count('done') == 4


def test_finished_cells_that_trained_with_other_settings_than_the_study_gives_now_are_refused(ran, tmp_path):
  study, out, _ = ran
  edited = tmp_path / 'mini.toml'  # The same cells, FreeNeRF's T moved after they ran.
  edited.write_text(TINY_STUDY.replace('"Config.freq_reg_end = 18"', '"Config.freq_reg_end = 17"'))
  before = {p: p.read_text() for p in pathlib.Path(out, 'mini').glob('*/*.json')}
  with pytest.raises(study_spec.StudyError, match=r'2 finished cell\(s\) trained with other settings') as error:
    study_lib.run_study(study_spec.load(edited), out)
  assert str(error.value).count('Config.freq_reg_end: 18 -> 17') == 2 and 'mipnerf' not in str(error.value)
  assert {p: p.read_text() for p in pathlib.Path(out, 'mini').glob('*/*.json')} == before
  assert study_lib.stale_cells(study, [(c, study_lib.cell_dir(study, c, out)) for c in study_spec.cells(study)],
                               out, 'data') == {}


def test_export_copies_results_metrics_pictures_and_provenance(ran, tmp_path):
  _, out, path = ran
  dest = tmp_path / 'export'
  assert study_lib.main([str(path), '--out', out, '--plots-only', '--export', str(dest)]) == 0
  assert (dest / 'results.csv').read_text() == pathlib.Path(out, 'mini', 'results.csv').read_text()
  assert not (dest / 'mini.toml').exists() and (dest / 'psnr_vs_views.png').is_file()
  assert not list(dest.rglob('checkpoints'))
  exported = json.loads((dest / 'provenance.json').read_text())
  assert exported['study_file']['sha256'] == hashlib.sha256(path.read_bytes()).hexdigest()
  assert exported['command'].startswith('python -m lab.study ') and '--export' in exported['command']
  assert 'cells' not in exported and sorted(p.name for p in dest.iterdir() if p.is_dir()) == []  # No cell folders.
  cells = cells_file.read(str(dest))
  assert sorted(cells) == sorted(c.cell_id for c in study_spec.cells(study_spec.load(path)))
  for cell, entry in cells.items():
    record, line = entry.line['record'], entry.line
    assert record == json.loads(pathlib.Path(out, 'mini', cell, 'cell.json').read_text())
    assert record['means'] == line['evaluation']['means'] and line['spec']['gin_bindings'][-1].endswith(
        f"'{{out}}/mini/{cell}/run'")                                  # The spec without this machine's paths.
    assert record['commit'].split('+')[0] == provenance.git_commit(str(REPO)).split('+')[0]
    changed = record['changed_files']  # The tree as the cell found it: a list, empty when clean.
    assert isinstance(changed, list) and bool(changed) == record['commit'].endswith('+dirty')
    run = pathlib.Path(out, 'mini', cell, study_lib.RUN_SUBDIR)
    texts = cells_file.files(line)                           # Each file as the run wrote it.
    assert texts['learning_curve.csv'] == (run / 'learning_curve.csv').read_bytes().decode()
    evaluated = run / f'test_preds_step_{record["step"]}'
    assert texts['metrics.csv'] == (evaluated / 'metrics.csv').read_bytes().decode()
    written = json.loads((evaluated / 'metrics.json').read_text())  # Its run folder as the spec names it.
    assert written['run_dir'] == str(run.resolve()) and texts['metrics.json'] == json.dumps(
        dict(written, run_dir=f'{{out}}/mini/{cell}/run'), indent=1)
  assert (dest / 'psnr_vs_step.png').is_file()
  table = (dest / 'table.md').read_text().splitlines()
  assert table[0].startswith('| method | scene | views | step | psnr |') and len(table) == 2 + 4
  assert all(f'| {float(r["psnr"]):.3f} |' in row for r, row in zip(_rows(dest / 'results.csv'), table[2:]))
  with pytest.raises(ValueError, match='exists and is not empty'):        # Never over an earlier export.
    study_lib.main([str(path), '--out', out, '--plots-only', '--export', str(dest)])
  assert json.loads((dest / 'provenance.json').read_text()) == exported
  h, w = 120, 160                                                         # 12 x 16 renders upscaled x10.
  for scene in ('object', 'forward'):
    with Image.open(dest / f'side_by_side_{scene}.png') as picture:    # Two views x (colour, depth) x (truth + 2).
      left0 = picture.size[0] - 3 * (w + vis.GAP)                       # The row titles fit their column.
      assert left0 == vis.label_width(['depth'] + [f'test view {i}' for i in range(10)])
      assert picture.size[1] == vis.HEADER + 4 * (h + vis.GAP)
      pixels = np.asarray(picture.convert('RGB'))
    depth_row = pixels[vis.HEADER + h + vis.GAP + h // 2]                # The exact depth under the truth (the
    truth_column = slice(left0, left0 + w)                                 # generated scene has one), the renders'
    render_columns = slice(left0 + w + vis.GAP, None)                     # beside it.
    assert (depth_row[truth_column] != 255).any(axis=-1).mean() > 0.5
    assert (depth_row[render_columns] != 255).any(axis=-1).mean() > 0.5


def test_tables_gather_the_study(ran, tmp_path):
  _, out, _ = ran
  assert tables.main([os.path.join(out, 'mini'), '--out', str(tmp_path)]) == 0
  blender = {r['scene']: r for r in _rows(tmp_path / 'blender_freenerf_3views.csv')}
  llff = {r['scene']: r for r in _rows(tmp_path / 'llff_mipnerf_3views.csv')}
  assert blender['generated_object']['note'] == 'not a protocol scene' and blender['mean']['PSNR'] == ''
  assert llff['generated_forward']['step'] == str(STEPS)
  cell = study_lib.read_cell(os.path.join(out, 'mini', 'freenerf__object__views=3'))
  assert float(blender['generated_object']['PSNR']) == pytest.approx(cell['means']['psnr'], abs=1e-6)


def test_pareto_front_by_hand():
  points = [(1., 10.), (2., 12.), (2., 11.), (3., 11.5), (4., 13.)]
  assert study_plots.pareto_front(points, False) == [(1., 10.), (2., 12.), (4., 13.)]
  assert study_plots.pareto_front([(1., .5), (2., .4), (3., .6)], True) == [(1., .5), (2., .4)]


def test_cells_and_gin_of_a_study():
  study = study_spec.parse(TINY_STUDY.replace('values = [3]', 'values = [3, 6]') + '''
[[axis]]
name = "M"
points = [{label = "M5", value = 5, bindings = ["Config.occ_reg_range = {M}"]}, {label = "off", bindings = []}]
''', 's.toml')
  cells = study_spec.cells(study)
  assert len(cells) == 2 * 2 * 2 * 2
  cell = cells[1]
  assert cell.cell_id == 'freenerf__object__views=3__M=off' and cell.expname == 'freenerf_M=off'
  configs_, bindings = study_spec.cell_gin(study, cells[0], 'O', 'D', 'O/mini/x')
  assert configs_ == [f'{REPO}/configs/demo.gin']
  assert "Config.data_dir = 'O/scenes/object'" in bindings and 'Config.n_input_views = 3' in bindings
  assert bindings[-3:] == ['Config.occ_reg_range = M5', "Config.expname = 'freenerf_M=M5'",
                           "Config.checkpoint_dir = 'O/mini/x'"]


@pytest.mark.parametrize('text, message', [
    ('name = "x"', r'bad\.toml: methods: missing'),
    ('name = "x"\n[methods.a]\nconfig = []\n[scenes.s]', r'bad\.toml: methods\.a: unknown keys \[\'config\'\]'),
    ('name = "x"\n[methods.a]\n[scenes.s]\nbindings = ["Config.data_dir = \'{root}\'"]',
     r"scenes\.s: .* unknown template fields \['root'\]"),
    ('name = "x"\n[methods.a]\n[scenes.s]\n[[axis]]\nname = "T"\nvalues = [1]', r'axis\[0\]: give either'),
    ('name = "x"\n[methods.a]\n[scenes.s]\n[plot]\nx = ["speed"]', r"plot\.x: 'speed' is neither"),
    ('name = 3', r'bad\.toml: name: 3 is a int; expected str'),
    ('name = "x"\n[methods.a', r'bad\.toml: not valid TOML'),
])
def test_bad_study_files_name_the_file_and_key(text, message):
  with pytest.raises(study_spec.StudyError, match=message):
    study_spec.parse(text, 'bad.toml')


def test_missing_study_file_is_an_error(tmp_path):
  with pytest.raises(study_spec.StudyError, match='does not exist'):
    study_spec.load(tmp_path / 'none.toml')


def test_committed_study_files_parse():
  files = sorted((REPO / 'studies').glob('*.toml'))
  assert files
  for path in files:
    study = study_spec.load(path)
    assert study_spec.cells(study)
    for cell in study_spec.cells(study):
      study_spec.cell_gin(study, cell, 'out', 'data', 'run')


def _cell_folder(root, name, renders):
  """A finished cell's folder under root: cell_spec.json and, with renders, one evaluated image."""
  evaluated = root / name / study_lib.RUN_SUBDIR / 'test_preds_step_20'
  evaluated.mkdir(parents=True)
  (root / name / 'cell_spec.json').write_text('{}')
  if renders:
    (evaluated / 'color_000.png').write_bytes(b'')
  return str(root / name)


def test_pictures_come_from_the_first_seed_whose_cells_kept_their_renders(tmp_path):
  cells = [{'cell': f'{m}_{s}', 'step': 20, 'labels': {study_spec.SEED_AXIS: s}} for s in ('1', '2') for m in 'ab']
  kept = {'a_1': True, 'b_1': False, 'a_2': True, 'b_2': True}           # b_1 was imported from an export.
  paths = {c['cell']: _cell_folder(tmp_path, c['cell'], kept[c['cell']]) for c in cells}
  assert study_export._picture_cells(cells, paths, ['1', '2']) == cells[2:]
  assert study_export._picture_cells(cells, paths, ['1']) == []


def test_cells_rendered_at_other_sizes_get_a_picture_of_their_own(tmp_path):
  cells = [{'cell': name, 'step': 20, 'labels': {}} for name in ('small', 'large', 'small_too')]
  paths = {c['cell']: _cell_folder(tmp_path, c['cell'], False) for c in cells}
  for name, size in (('small', (16, 12)), ('large', (32, 24)), ('small_too', (16, 12))):
    Image.new('RGB', size).save(pathlib.Path(paths[name], study_lib.RUN_SUBDIR, 'test_preds_step_20', 'color_000.png'))
  groups = study_export._by_render_size('object', cells, paths)  # pylint: disable=protected-access
  assert [(name, [c['cell'] for c in group]) for name, group in groups] == [
      ('side_by_side_object.png', ['small', 'small_too']), ('side_by_side_object_24x32.png', ['large'])]


def test_an_out_folder_moved_since_its_cells_ran_exports_no_path_of_where_they_ran(ran, tmp_path):
  _, out, path = ran
  moved = tmp_path / 'elsewhere' / 'out'
  shutil.copytree(out, moved)  # Its metrics.json files still name the run folders where they were.
  dest = tmp_path / 'export'
  assert study_lib.main([str(path), '--out', str(moved), '--plots-only', '--export', str(dest)]) == 0
  for cell, entry in cells_file.read(str(dest)).items():
    assert json.loads(cells_file.files(entry.line)['metrics.json'])['run_dir'] == f'{{out}}/mini/{cell}/run'
  assert str(out) not in (dest / 'cells.jsonl').read_text()


def test_export_without_renders_warns_and_draws_no_picture(ran, tmp_path, capsys):
  _, out, path = ran
  copy = tmp_path / 'out'
  shutil.copytree(out, copy)
  for image in (copy / 'mini').glob('*object*/run/test_preds_step_*/color_*.png'):
    image.unlink()
  assert study_lib.main([str(path), '--out', str(copy), '--plots-only', '--export', str(tmp_path / 'x')]) == 0
  assert 'warning: side_by_side_object.png not drawn' in capsys.readouterr().out
  assert not (tmp_path / 'x' / 'side_by_side_object.png').exists()
  assert (tmp_path / 'x' / 'side_by_side_forward.png').is_file()


def test_an_export_that_fails_half_way_leaves_no_folder_and_the_retry_succeeds(ran, tmp_path, monkeypatch):
  _, out, path = ran
  dest = tmp_path / 'export'

  def fail(*_):
    raise ValueError('Config.data_dir = \'x\' does not exist')
  with monkeypatch.context() as patched:                    # Fails at the pictures, after the csv and cells.
    patched.setattr(study_export, '_scene_picture', fail)
    with pytest.raises(ValueError, match='does not exist'):
      study_lib.main([str(path), '--out', out, '--plots-only', '--export', str(dest)])
  assert sorted(os.listdir(tmp_path)) == []                 # Neither dest nor its staging folder.
  assert study_lib.main([str(path), '--out', out, '--plots-only', '--export', str(dest)]) == 0
  assert (dest / 'provenance.json').is_file() and (dest / 'side_by_side_object.png').is_file()
  assert sorted(os.listdir(tmp_path)) == ['export']


def test_reuse_takes_the_exported_cells_with_the_same_settings(ran, tmp_path, capsys):
  _, out, path = ran
  export = tmp_path / 'export'
  assert study_lib.main([str(path), '--out', out, '--plots-only', '--export', str(export)]) == 0
  fresh = tmp_path / 'fresh'                                             # Another machine: no run folders.
  assert study_lib.main([str(path), '--out', str(fresh), '--reuse', str(export), '--plots-only']) == 0
  assert capsys.readouterr().out.count('reused ') == 4
  columns = ('cell', 'psnr', 'steps_per_sec', 'status')
  pick = lambda rows: [{k: r[k] for k in columns} for r in rows]
  assert pick(_rows(fresh / 'mini' / 'results.csv')) == pick(_rows(pathlib.Path(out, 'mini', 'results.csv')))
  assert (fresh / 'mini' / 'psnr_vs_step.png').is_file()                 # The learning curves came along.
  cell = study_spec.cells(study_spec.load(path))[0].cell_id
  for name in ('metrics.csv', 'metrics.json'):                           # Placed as the run wrote them (its run
    placed = fresh / 'mini' / cell / study_lib.RUN_SUBDIR / f'test_preds_step_{STEPS}' / name  # folder templated).
    ran = pathlib.Path(out, 'mini', cell, study_lib.RUN_SUBDIR, placed.parent.name, name).read_text()
    assert placed.read_text() == ran.replace(str(pathlib.Path(out).resolve()), '{out}')
  renamed = tmp_path / 'mini_again.toml'                                 # Another study taking the same cells:
  renamed.write_text(path.read_text().replace('name = "mini"', 'name = "mini_again"'))
  again = tmp_path / 'again'                                             # its export refers to the first one.
  assert study_lib.main([str(renamed), '--out', str(tmp_path / 'fresh2'), '--reuse', str(export), '--plots-only',
                         '--export', str(again)]) == 0
  assert capsys.readouterr().out.count('reused ') == 4
  lines = [json.loads(l) for l in (again / 'cells.jsonl').read_text().splitlines()]
  assert lines and all(l == {'cell': l['cell'], 'same_as': '../export'} for l in lines)
  assert {c: e.line for c, e in cells_file.read(str(again)).items()} == {
      c: e.line for c, e in cells_file.read(str(export)).items()}
  changed = tmp_path / 'changed'                                         # An export of another version of the file.
  shutil.copytree(export, changed)
  other_version = tmp_path / 'mini_v2.toml'
  other_version.write_text(path.read_text().replace('"Config.freq_reg_end = 0"', '"Config.freq_reg_end = 5"'))
  _set_study_file(changed, other_version)
  assert study_lib.main([str(path), '--out', str(tmp_path / 'other'), '--reuse', str(changed), '--list']) == 0
  listing = capsys.readouterr().out
  assert listing.count('reused ') == 2 and listing.count('not reused') == 2 and listing.count('pending') == 2
  other_version.write_text('name = "edited since"')                      # That version is nowhere now.
  with pytest.raises(study_spec.StudyError, match='which neither that file here nor its git history holds'):
    study_lib.main([str(path), '--out', str(tmp_path / 'other'), '--reuse', str(changed), '--list'])
  with pytest.raises(study_spec.StudyError, match='no provenance.json there'):
    study_lib.main([str(path), '--out', str(tmp_path / 'none'), '--reuse', str(tmp_path), '--list'])


def _set_study_file(export, study_file):
  """Makes an export's provenance.json name study_file (path and SHA-256) as the study file it ran."""
  provenance = json.loads((export / 'provenance.json').read_text())
  provenance['study_file'] = {'path': str(study_file), 'sha256': hashlib.sha256(study_file.read_bytes()).hexdigest()}
  (export / 'provenance.json').write_text(json.dumps(provenance))


def test_a_dirty_commit_names_the_files_that_differ(tmp_path):
  git = lambda *args: subprocess.run(['git', '-C', str(tmp_path), *args], check=True, capture_output=True)
  git('init', '-q')
  for name in ('a.py', 'b.py'):
    (tmp_path / name).write_text('x = 1\n')
  git('add', '.')
  git('-c', 'user.name=t', '-c', 'user.email=t@t', 'commit', '-qm', 'c')
  assert provenance.changed_files(str(tmp_path)) == []
  assert not provenance.git_commit(str(tmp_path)).endswith('+dirty')
  (tmp_path / 'b.py').write_text('x = 2\n')
  (tmp_path / 'untracked.py').write_text('')
  commit, changed = provenance.code_state(str(tmp_path))
  assert changed == provenance.changed_files(str(tmp_path)) == ['b.py']
  assert commit.endswith('+dirty') and commit == provenance.git_commit(str(tmp_path))
  assert provenance.changed_files(str(tmp_path / 'nowhere')) == []
  assert provenance.code_state(str(tmp_path / 'nowhere')) == ('unknown', [])
