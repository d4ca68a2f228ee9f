"""Unhandled inputs and faults: each is a one-line user error naming the setting or file, or behaves correctly."""

import errno

import pytest

import eval as eval_script
import train as train_script
from internal import atomic
from internal import cli
from internal.training import run_dir as run_dir_lib
from test_checkpoints import DEMO, tiny_config


def _cli(monkeypatch, capsys, main, *argv) -> tuple:
  """(exit status, stderr) of a script's main(argv) run as its command line runs it."""
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  status = cli.run(lambda: main(['--gin_configs', DEMO, '--gin_bindings', *argv]))
  return status, capsys.readouterr().err


def _one_error_line(errout: str, *fragments) -> None:
  """errout is one `error: ...` line holding every fragment."""
  assert errout.startswith('error: ') and errout.count('\n') == 1, errout
  for fragment in fragments:
    assert fragment in errout, (fragment, errout)


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


def test_zero_render_path_frames_is_refused_naming_the_setting():
  with pytest.raises(ValueError, match=r'Config\.render_path_frames = 0; expected a positive integer'):
    tiny_config('s', 'run', 'Config.render_path_frames = 0')
