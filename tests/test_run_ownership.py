"""Config.overwrite deletes only what this project wrote, and only in a run of this project (its marker file)."""

import json
import os

import pytest

import eval as eval_script
import render as render_script
import train as train_script
from internal import cli
from internal.evaluation import evaluate
from internal.evaluation import learning_curve
from internal.evaluation import render_path
from internal.run import checkpoints
from internal.pipeline import loop
from internal.run import run_dir as run_dir_lib
from test_checkpoints import TINY, tiny_config
from test_run_dir_errors import _cli, _one_error_line

# A folder of another tool: a model's config.json (a name we use too), its weights and the user's notes.
FOREIGN = {'config.json': json.dumps({'architectures': ['BertModel'], 'hidden_size': 768, 'batch_size': 4096}),
           'model.safetensors': 'weights', 'notes.txt': 'mine'}


def _contents(folder) -> dict:
  """{relative path: bytes} of every file under folder."""
  return {str(p.relative_to(folder)): p.read_bytes().decode(errors='replace') for p in sorted(folder.rglob('*'))
          if p.is_file()}


def _foreign_folder(tmp_path):
  folder = tmp_path / 'model'
  folder.mkdir()
  for name, text in FOREIGN.items():
    (folder / name).write_text(text)
  return folder


@pytest.mark.parametrize('overwrite', [True, False])
def test_a_foreign_folder_with_a_config_json_is_never_touched(tmp_path, monkeypatch, capsys, overwrite):
  folder = _foreign_folder(tmp_path)
  status, errout = _cli(monkeypatch, capsys, train_script.main, *TINY, f"Config.checkpoint_dir = '{folder}'",
                        f'Config.overwrite = {overwrite}')
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, f'Config.checkpoint_dir {str(folder)!r} is not a run of this project',
                  'config.json is not settings of this project', 'choose another Config.checkpoint_dir')
  assert _contents(folder) == FOREIGN
  with pytest.raises(run_dir_lib.RunDirError, match='is not a run of this project'):
    run_dir_lib.check_trainable(tiny_config('s', folder, f'Config.overwrite = {overwrite}'))


@pytest.mark.parametrize('main', [eval_script.main, render_script.main])
def test_eval_and_render_say_a_foreign_folder_is_not_a_run(tmp_path, monkeypatch, capsys, main):
  folder = _foreign_folder(tmp_path)
  status, errout = _cli(monkeypatch, capsys, main, *TINY, f"Config.checkpoint_dir = '{folder}'")
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, f'Config.checkpoint_dir {str(folder)!r} is not a run of this project')
  assert _contents(folder) == FOREIGN


def test_a_folder_of_other_files_is_named_not_a_run(tmp_path):
  (tmp_path / 'photos').mkdir()
  (tmp_path / 'photos' / 'a.jpg').write_text('jpeg')
  with pytest.raises(run_dir_lib.RunDirError, match=r"not a run of this project \(no freenerf_jax_run.json; it "
                                                    r"holds \['a.jpg'\]\)"):
    run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path / 'photos', 'Config.overwrite = True'))
  assert _contents(tmp_path / 'photos') == {'a.jpg': 'jpeg'}


@pytest.mark.parametrize('keys', [
    {'Config.batch_size': 1},                                                   # Too few of our names.
    {'Config.batch_size': 1, 'Config.max_steps': 1, 'Config.lr_init': 1., 'Config.n_input_views': 3, 'lr': 1.}])
def test_settings_of_an_earlier_version_are_told_from_other_json(tmp_path, keys):
  (tmp_path / 'run').mkdir()
  (tmp_path / 'run' / 'config.json').write_text(json.dumps(keys))
  with pytest.raises(run_dir_lib.RunDirError, match='is not a run of this project'):
    run_dir_lib.prepare_run_dir(tiny_config('s', tmp_path / 'run', 'Config.overwrite = True'))
  assert os.listdir(tmp_path / 'run') == ['config.json']


def test_a_run_of_an_earlier_version_resumes_and_is_marked(tmp_path, scene_dir):
  run = tmp_path / 'run'
  config = lambda: tiny_config(scene_dir, run, 'Config.max_steps = 4')
  loop.train(config(), stop_at_step=2)
  (run / run_dir_lib.MARKER_FILE).unlink()  # As an earlier version left it.
  (run / 'notes.txt').write_text('mine')
  assert run_dir_lib.check_run_dir(config()) == str(run)  # eval.py and render.py read it.
  assert not (run / run_dir_lib.MARKER_FILE).exists()
  result = loop.train(config())
  assert int(result.state.step) == 4 and checkpoints.latest_step(str(run)) == 4
  assert run_dir_lib.is_marked(str(run))
  assert (run / 'notes.txt').read_text() == 'mine'


def test_overwrite_of_an_earlier_versions_run_deletes_only_its_files(tmp_path):
  run = tmp_path / 'run'
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(tiny_config('s', run)), tiny_config('s', run))
  (run / run_dir_lib.MARKER_FILE).unlink()
  (run / 'checkpoints' / '5').mkdir(parents=True)
  (run / 'notes.txt').write_text('mine')
  with pytest.raises(run_dir_lib.RunDirError, match='different settings'):
    run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 9'))
  run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 9', 'Config.overwrite = True'))
  assert sorted(os.listdir(run)) == [run_dir_lib.MARKER_FILE, 'notes.txt'] and run_dir_lib.is_marked(str(run))


def test_overwrite_of_a_run_deletes_everything_it_wrote_and_nothing_else(tmp_path, scene_dir):
  run = tmp_path / 'run'
  config = tiny_config(scene_dir, run, 'Config.max_steps = 2', 'Config.render_path_frames = 2',
                       'Config.compute_lpips = False')
  loop.train(config)
  evaluate.evaluate(config)
  render_path.render(config)
  outputs = [os.path.basename(f(str(run), 2)) for f in (evaluate.output_dir, render_path.output_dir)]
  owned = sorted(p.name for p in run.iterdir() if p.is_dir())  # Every folder the run writes into: a user file in each.
  assert owned == sorted(['checkpoints', 'tensorboard', *outputs])
  user = {'notes.txt': 'mine', **{os.path.join(name, 'README'): f'mine, in {name}' for name in owned}}
  for name, text in user.items():
    (run / name).write_text(text)
  assert len(_contents(run)) > 30  # Checkpoints, tensorboard, the evaluation and the renders.
  loop.train(tiny_config(scene_dir, run, 'Config.max_steps = 3', 'Config.overwrite = True'), stop_at_step=1)
  fresh = {'config.gin', 'config.json', run_dir_lib.MARKER_FILE, 'notes.txt', learning_curve.CLOCK_FILE, *owned}
  # No learning curve at step 1, only its clock (saved with every checkpoint).
  assert set(os.listdir(run)) == fresh
  assert {name: (run / name).read_text() for name in user} == user
  for name in outputs:  # Of the evaluation's and the renders' folders only the user's file is left.
    assert _contents(run / name) == {'README': f'mine, in {name}'}
  assert checkpoints.latest_step(str(run)) == 1
  assert run_dir_lib.read_fingerprint(str(run))['Config.max_steps'] == 3


def test_a_marked_run_without_its_settings_is_not_resumed_with_others(tmp_path):
  run = tmp_path / 'run'
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(tiny_config('s', run)), tiny_config('s', run))
  (run / 'checkpoints' / '7').mkdir(parents=True)
  (run / 'config.json').unlink()
  with pytest.raises(run_dir_lib.RunDirError, match=r"holds files of a run \(\['checkpoints', 'config.gin'\]\) but "
                                                    r"not its settings \(config.json is missing\)"):
    run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 9'))
  run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 9', 'Config.overwrite = True'))
  assert os.listdir(run) == [run_dir_lib.MARKER_FILE]


def _recorded_run(run):
  """A run directory with its marker and settings, as training starts one."""
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(tiny_config('s', run)), tiny_config('s', run))


def _make(folder, names):
  """Creates each name under folder: a folder when it ends with '/', else a file."""
  for name in names:
    path = folder / name.rstrip('/')
    path.parent.mkdir(parents=True, exist_ok=True)
    path.mkdir() if name.endswith('/') else path.write_text('x')


def test_overwrite_deletes_names_of_the_exact_forms_this_project_writes(tmp_path):
  run = tmp_path / 'run'
  _recorded_run(run)
  ours = ['checkpoints/8/', 'checkpoints/8.orbax-checkpoint-tmp/', 'checkpoints/damaged_4_20240101-120000/',
          'test_preds_step_8/color_001.png', 'test_preds_step_8/metrics.json', '.config.gin.a1b2c3d4.tmp']
  users = ['checkpoints/8_best/meta', 'checkpoints/8 copy/meta', 'checkpoints/damaged_4_mine/',
           'test_preds_step_8/color_001_edited.png', 'test_preds_step_8_best/metrics.json', 'config.json.bak']
  _make(run, ours + users)
  run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 400', 'Config.overwrite = True'))
  left = {str(p.relative_to(run)) + ('/' if p.is_dir() else '') for p in run.rglob('*')}
  assert set(users) <= left and not left & set(ours), left


def test_overwrite_clears_the_steps_of_a_linked_checkpoints_folder_and_keeps_the_link(tmp_path):
  run, disk = tmp_path / 'run', tmp_path / 'other_disk' / 'checkpoints'
  _recorded_run(run)
  _make(disk, ['8/', '12/', 'notes.txt'])
  (run / 'checkpoints').symlink_to(disk, target_is_directory=True)
  run_dir_lib.prepare_run_dir(tiny_config('s', run, 'Config.max_steps = 400', 'Config.overwrite = True'))
  assert (run / 'checkpoints').is_symlink() and sorted(os.listdir(disk)) == ['notes.txt']  # No old step resumes.


@pytest.mark.parametrize('main', [eval_script.main, render_script.main])
def test_an_output_dir_inside_another_run_is_refused(tmp_path, monkeypatch, capsys, main):
  run, other = tmp_path / 'run', tmp_path / 'other'
  _recorded_run(run)
  _recorded_run(other)
  status, errout = _cli(monkeypatch, capsys, main, *TINY, f"Config.checkpoint_dir = '{run}'",
                        f"Config.output_dir = '{other / 'evals'}'")
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, f"Config.output_dir {str(other / 'evals')!r} is inside {str(other)!r}, another run of "
                          'this project', 'choose a folder outside other runs')
  assert not (other / 'evals').exists()
  for fine in (run / 'evals', tmp_path / 'evals'):  # Inside its own run, or outside every run.
    assert run_dir_lib.check_run_dir(tiny_config('s', run, f"Config.output_dir = '{fine}'")) == str(run)
