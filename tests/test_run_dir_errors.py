"""The run directory's errors as one line naming Config.checkpoint_dir (unwritable, read-only, a file), and eval and
render refusing a model or data setting other than the run's."""

import errno
import types

import pytest

import eval as eval_script
import render as render_script
import train as train_script
from internal import atomic
from internal import cli
from internal.pipeline import loop
from internal.run import run_dir as run_dir_lib
from test_checkpoints import DEMO, TINY, tiny_config


def _cli(monkeypatch, capsys, main, *argv) -> tuple:
  """(exit status, stderr) of a script's main(argv) run as its command line runs it."""
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  status = cli.run(lambda: main(['--gin_configs', DEMO, '--gin_bindings', *argv]))
  return status, capsys.readouterr().err



def _one_error_line(errout: str, *fragments) -> None:
  """errout ends with one `error: ...` line (after any progress bar) holding every fragment."""
  line = errout.splitlines()[-1]
  assert line.startswith('error: ') and errout.count('error: ') == 1, errout
  for fragment in fragments:
    assert fragment in line, (fragment, errout)



def test_a_run_directory_under_a_regular_file_is_a_one_line_error(tmp_path, monkeypatch, capsys):
  (tmp_path / 'file').write_text('not a folder')
  run = tmp_path / 'file' / 'run'
  status, errout = _cli(monkeypatch, capsys, train_script.main, f"Config.checkpoint_dir = '{run}'")
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, 'Config.checkpoint_dir', repr(str(run)), 'cannot be written', 'expected a writable')



def test_a_read_only_run_directory_is_a_one_line_error(tmp_path, monkeypatch, capsys):
  def read_only(path, text):
    raise OSError(errno.EROFS, 'Read-only file system', str(path))
  monkeypatch.setattr(atomic, 'write_text', read_only)  # Root ignores chmod: fail where the lock is written.
  status, errout = _cli(monkeypatch, capsys, train_script.main, f"Config.checkpoint_dir = '{tmp_path / 'run'}'")
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, 'Config.checkpoint_dir', repr(str(tmp_path / 'run')), 'Read-only file system')



@pytest.mark.parametrize('main', [train_script.main, eval_script.main])
def test_a_checkpoint_dir_that_is_a_file_is_named_as_such(tmp_path, monkeypatch, capsys, main):
  (tmp_path / 'run').write_text('a file')
  status, errout = _cli(monkeypatch, capsys, main, f"Config.checkpoint_dir = '{tmp_path / 'run'}'")
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, 'Config.checkpoint_dir', 'is an existing file; expected a directory')



def _recorded_run(run) -> None:
  """A run directory holding the settings of tiny_config (what training records before its first step)."""
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(tiny_config('s', run)), tiny_config('s', run))



@pytest.mark.parametrize('main', [eval_script.main, render_script.main])
@pytest.mark.parametrize('binding, named', [
    ('MLP.net_width = 48', 'MLP.net_width: 32 -> 48'),
    ('MipNerfModel.num_samples = 8', 'MipNerfModel.num_samples: 16 -> 8'),
    ('Config.factor = 2', 'Config.factor: 0 -> 2'),
    ('Config.generated_size = (16, 20)', 'Config.generated_size: [32, 40] -> [16, 20]')])
def test_eval_and_render_refuse_a_model_or_data_setting_other_than_the_runs(tmp_path, monkeypatch, capsys, main,
                                                                            binding, named):
  _recorded_run(tmp_path / 'run')
  status, errout = _cli(monkeypatch, capsys, main, *TINY, "Config.data_dir = 's'",
                        f"Config.checkpoint_dir = '{tmp_path / 'run'}'", binding)
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, 'was trained with different settings', named)



@pytest.mark.parametrize('binding', [
    'Config.render_chunk_size = 64', 'Config.eval_test_ids = [0, 2]', 'Config.compute_lpips = False',
    "Config.lpips_weights_path = 'w.npz'", "Config.lpips_input_range = 'official'", "Config.depth_reference_dir = 'd'",
    'Config.render_path_frames = 3', 'Config.render_factor = 2', 'Config.eval_factor = 2', 'Config.print_every = 7',
    'Config.checkpoint_every = 9', 'Config.stuck_warning_steps = 0', "Config.data_dir = 'moved'"])
def test_eval_and_render_settings_that_change_neither_model_nor_data_stay_free(tmp_path, binding):
  _recorded_run(tmp_path / 'run')
  assert run_dir_lib.check_run_dir(tiny_config('s', tmp_path / 'run', binding)) == str(tmp_path / 'run')


def test_a_leading_tilde_in_a_path_setting_is_the_home_folder(tmp_path, monkeypatch):
  monkeypatch.setenv('HOME', str(tmp_path))
  monkeypatch.chdir(tmp_path)
  config = tiny_config('~/scene', '~/runs/fern', "Config.output_dir = '~'")
  assert (config.checkpoint_dir, config.data_dir, config.output_dir) == (
      str(tmp_path / 'runs' / 'fern'), str(tmp_path / 'scene'), str(tmp_path))
  run_dir_lib.prepare_run_dir(config)
  assert (tmp_path / 'runs' / 'fern').is_dir() and not (tmp_path / '~').exists()


def test_a_tilde_of_an_unknown_user_is_refused_naming_the_setting():
  with pytest.raises(ValueError, match=r"Config.checkpoint_dir = '~no_such_user_x/runs': no home folder of user "
                                       r"'no_such_user_x'"):
    tiny_config('s', '~no_such_user_x/runs')


@pytest.mark.parametrize('signum, said', [(None, "Trained to step 5; run directory '{}'."),
                                          (2, "checkpoint saved in '{}'. Run the same command again")])
def test_the_final_line_of_training_names_the_absolute_run_directory(tmp_path, monkeypatch, capsys, signum, said):
  monkeypatch.chdir(tmp_path)
  monkeypatch.setattr(loop, 'train', lambda config, stop_at_step: loop.TrainResult(
      None, types.SimpleNamespace(step=5), 'runs/fern', signum))
  train_script.train_and_report(tiny_config('s', 'runs/fern'))
  assert said.format(tmp_path / 'runs' / 'fern') in capsys.readouterr().out.strip().splitlines()[-1]
