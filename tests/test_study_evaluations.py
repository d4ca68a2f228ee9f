"""lab.study's further evaluations ([evaluations.<name>], lab/study/evaluations.py): each finished cell's model
evaluated again under bookkeeping settings, without training it again; columns <metric>@<name>; export and reuse."""

import csv
import json
import os
import pathlib

import pytest

from lab.study import evaluations
from lab.study import runner as study_lib
from lab.study import spec as study_spec

REPO = pathlib.Path(__file__).resolve().parents[1]
STUDY = f'''
name = "again"
bindings = ["MLP.net_depth = 2", "MLP.net_width = 16", "MLP.net_width_viewdirs = 16",
            "MipNerfModel.num_samples = 8", "Config.batch_size = 64", "Config.max_steps = 10",
            "Config.print_every = 10", "Config.checkpoint_every = 10", "Config.compute_lpips = False",
            "Config.render_chunk_size = 192", "Config.curve_every = 0", "Config.generated_size = (12, 16)",
            "Config.data_dir = '{{out}}/scenes/object'", "Config.generated_rig = 'object'", "Config.n_input_views = 3",
            "Config.camera_noise_rotation_deg = 3.", "Config.camera_noise_translation = 0.03"]
[methods.refine]
configs = ["{REPO}/configs/demo.gin", "{REPO}/configs/common/camera_refinement.gin"]
[scenes.object]
bindings = []
[evaluations.test_pose]
bindings = ["Config.test_pose_steps = 4", "Config.test_pose_lr = 1e-2"]
'''
FIRST_VIEW = '''
[evaluations.first_view]
bindings = ["Config.eval_test_ids = (0,)"]
'''


def _rows(path):
  with open(path, newline='') as f:
    return list(csv.DictReader(f))


def _study(tmp_path, text, name='again.toml'):
  path = tmp_path / name
  path.write_text(text)
  return study_spec.load(path), path


@pytest.fixture(scope='module', name='ran')
def fixture_ran(tmp_path_factory):
  """(study file, out) after the one-cell study ran in this process."""
  root = tmp_path_factory.mktemp('evaluations')
  study, path = _study(root, STUDY)
  out = str(root / 'out')
  assert study_lib.run_study(study, out) == {}
  return path, out


def _cell(out):
  return pathlib.Path(out, 'again', 'refine__object')


def test_a_cell_is_evaluated_again_with_the_evaluations_bindings_into_its_own_columns(ran):
  _, out = ran
  row, = _rows(pathlib.Path(out, 'again', study_lib.RESULTS_FILE))
  plain = json.loads((_cell(out) / 'run' / 'test_preds_step_10' / 'metrics.json').read_text())
  again = json.loads(pathlib.Path(evaluations.metrics_path(str(_cell(out)), 'test_pose', 10)).read_text())
  assert plain['cameras']['test_pose_steps'] == 0 and again['cameras']['test_pose_steps'] == 4
  assert again['cameras']['test_cameras'] == 'similarity + test-time pose optimization'
  assert float(row['psnr']) == pytest.approx(plain['means']['psnr'], rel=1e-12)
  assert float(row['psnr@test_pose']) == pytest.approx(again['means']['psnr'], rel=1e-12)
  assert row['psnr@test_pose'] != row['psnr']             # The test cameras moved: another rendering.
  assert row['camera_rotation_deg@test_pose'] == row['camera_rotation_deg']  # The training cameras did not.
  assert 'test_pose_rotation_deg' not in row and float(row['test_pose_rotation_deg@test_pose']) > 0.
  recorded = json.loads((_cell(out) / 'evaluations' / 'test_pose' / 'bindings.json').read_text())
  assert recorded == ['Config.test_pose_steps = 4', 'Config.test_pose_lr = 1e-2']


def test_an_evaluation_added_later_runs_on_the_finished_cell_without_training_it_again(ran, tmp_path):
  path, out = ran
  before = (_cell(out) / 'cell.json').read_text()
  checkpoints = sorted(os.listdir(_cell(out) / 'run' / 'checkpoints'))
  study, _ = _study(tmp_path, path.read_text() + FIRST_VIEW)
  assert study_lib.run_study(study, out) == {}
  row, = _rows(pathlib.Path(out, 'again', study_lib.RESULTS_FILE))
  assert (_cell(out) / 'cell.json').read_text() == before
  assert sorted(os.listdir(_cell(out) / 'run' / 'checkpoints')) == checkpoints
  first = json.loads(pathlib.Path(evaluations.metrics_path(str(_cell(out)), 'first_view', 10)).read_text())
  assert first['test_positions'] == [0] and not first['complete']
  assert float(row['psnr@first_view']) == pytest.approx(first['means']['psnr'], rel=1e-12)
  assert row['psnr@test_pose']                               # Not run again, still gathered.


def test_an_evaluation_whose_bindings_changed_since_it_ran_is_refused_naming_its_file(ran, tmp_path):
  path, out = ran
  changed, _ = _study(tmp_path, path.read_text().replace('"Config.test_pose_steps = 4"', '"Config.test_pose_steps = 5"'))
  cell = str(_cell(out))
  os.remove(evaluations.metrics_path(cell, 'test_pose', 10))   # Its outputs gone, its bindings.json left.
  failed = study_lib.run_study(changed, out)
  assert list(failed) == [cell] and "bindings.json: the evaluation 'test_pose' ran with" in failed[cell]
  assert study_lib.run_study(study_spec.load(path), out) == {}  # The study as it ran evaluates it again.
  assert os.path.isfile(evaluations.metrics_path(cell, 'test_pose', 10))


def test_bindings_that_change_what_the_run_trained_are_refused_before_it_is_evaluated(ran, tmp_path):
  path, out = ran
  text = path.read_text() + '[evaluations.other_t]\nbindings = ["Config.freq_reg_end_fraction = 0.2"]\n'
  failed = study_lib.run_study(_study(tmp_path, text)[0], out)
  assert list(failed) == [str(_cell(out))] and 'change what the run trained (Config.freq_reg_end: 5 -> 2' in (
      failed[str(_cell(out))])
  assert not (_cell(out) / 'evaluations' / 'other_t').exists()


def test_export_carries_the_evaluations_and_reuse_places_them_back(ran, tmp_path, capsys):
  path, out = ran
  export = tmp_path / 'export'
  assert study_lib.main([str(path), '--out', out, '--plots-only', '--export', str(export)]) == 0
  line, = [json.loads(l) for l in (export / 'cells.jsonl').read_text().splitlines()]
  assert sorted(line['evaluations']) == ['test_pose']
  assert line['evaluations']['test_pose']['evaluation']['run_dir'] == '{out}/again/refine__object/run'
  fresh = tmp_path / 'fresh'
  assert study_lib.main([str(path), '--out', str(fresh), '--reuse', str(export), '--plots-only']) == 0
  columns = ('psnr', 'psnr@test_pose')
  pick = lambda rows: [{k: r[k] for k in columns} for r in rows]
  assert pick(_rows(fresh / 'again' / 'results.csv')) == pick(_rows(pathlib.Path(out, 'again', 'results.csv')))
  more, more_path = _study(tmp_path, path.read_text() + FIRST_VIEW, 'more.toml')  # Asked of a cell without its run:
  capsys.readouterr()
  assert study_lib.run_study(more, str(fresh)) == {}                             # named, nothing fails.
  assert "evaluations ['first_view'] not run: the cell came without its checkpoints" in capsys.readouterr().out
  assert more_path.is_file()


@pytest.mark.parametrize('table, message', [
    ('[evaluations.bad]\nbindings = ["Config.max_steps = 5"]', 'evaluations.bad.bindings: .Config.max_steps = 5.: '
                                                              'expected Config.<setting> = value of a setting that'),
    ('[evaluations.bad]\nbindings = ["Config.output_dir = \'x\'"]', 'Config.output_dir is set by the runner'),
    ('[evaluations.bad]\nbindings = ["MLP.net_width = 8"]', 'expected Config.<setting> = value'),
    ('[evaluations.bad]\nbindings = []', 'evaluations.bad.bindings: is empty'),
    ('[evaluations.a-b]\nbindings = ["Config.test_pose_steps = 1"]', 'evaluations.a-b: the name must be an identifier'),
    ('[evaluations.bad]\nbindings = ["Config.test_pose_steps = 1"]\nsteps = 3', "unknown keys \\['steps'\\]"),
])
def test_bad_evaluations_name_the_file_and_key(tmp_path, table, message):
  with pytest.raises(study_spec.StudyError, match=f'again.toml: .*{message}'):
    _study(tmp_path, STUDY.split('[evaluations.test_pose]')[0] + table)
