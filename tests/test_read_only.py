"""Read-only folders: eval.py and render.py of a shared run write to Config.output_dir; training names the folder."""

import contextlib
import os
import subprocess

import pytest

import eval as eval_script
import render as render_script
import train as train_script
from internal import cli
from internal.pipeline import loop
from test_checkpoints import TINY, tiny_config
from test_run_dir_errors import _cli, _one_error_line

BINDINGS = ('Config.max_steps = 2', 'Config.render_path_frames = 2', 'Config.compute_lpips = False')


@contextlib.contextmanager
def read_only(folder):
  """folder read-only for this process: a read-only bind mount for root (who ignores permissions), else chmod."""
  folder = str(folder)
  if os.geteuid() != 0:
    modes = {p: os.stat(p).st_mode for p in [folder] + [os.path.join(d, n) for d, ds, fs in os.walk(folder)
                                                        for n in ds + fs]}
    for path, mode in modes.items():
      os.chmod(path, mode & ~0o222)
    try:
      yield
    finally:
      for path, mode in modes.items():
        os.chmod(path, mode)
    return
  mount = subprocess.run(['mount', '--bind', folder, folder], capture_output=True, text=True, check=False)
  if mount.returncode:
    pytest.skip(f'cannot bind-mount {folder} read-only here: {mount.stderr.strip()}')
  try:
    subprocess.run(['mount', '-o', 'remount,bind,ro', folder], check=True)
    yield
  finally:
    subprocess.run(['umount', folder], check=True)


def _snapshot(folder) -> dict:
  """{relative path: (size, mtime)} of everything under folder, folder itself included."""
  out = {'.': os.stat(folder).st_mtime_ns}
  for d, ds, fs in os.walk(folder):
    for name in ds + fs:
      path = os.path.join(d, name)
      out[os.path.relpath(path, folder)] = (os.path.getsize(path), os.stat(path).st_mtime_ns)
  return out


@pytest.fixture(scope='module')
def finished_run(tmp_path_factory, scene_dir):
  """A run directory trained for 2 steps (its scene written)."""
  run = tmp_path_factory.mktemp('shared') / 'run'
  loop.train(tiny_config(scene_dir, run, *BINDINGS))
  return run


def _flags(run, scene_dir, *extra) -> list:
  return [*TINY, *BINDINGS, f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'", *extra]


@pytest.mark.parametrize('main, folder', [(eval_script.main, 'test_preds_step_2'),
                                          (render_script.main, 'path_renders_step_2')])
def test_a_read_only_run_writes_its_outputs_to_output_dir(finished_run, scene_dir, tmp_path, monkeypatch, capsys,
                                                          main, folder):
  before = _snapshot(finished_run)
  with read_only(finished_run):
    status, errout = _cli(monkeypatch, capsys, main, *_flags(finished_run, scene_dir))
    assert status == cli.USAGE_ERROR_STATUS
    _one_error_line(errout, f'Config.checkpoint_dir {str(finished_run)!r} cannot be written',
                    f'{os.path.join(finished_run, folder)!r}', 'set Config.output_dir to a writable folder')
    status, errout = _cli(monkeypatch, capsys, main, *_flags(finished_run, scene_dir,
                                                             f"Config.output_dir = '{tmp_path / 'out'}'"))
    assert status == 0, errout
  assert 'Traceback' not in errout
  assert os.listdir(tmp_path / 'out') == [folder] and len(os.listdir(tmp_path / 'out' / folder)) >= 6
  assert _snapshot(finished_run) == before  # Nothing written into the run, not even a lock.


def test_an_unwritable_output_dir_is_named(finished_run, scene_dir, tmp_path, monkeypatch, capsys):
  (tmp_path / 'out').mkdir()
  with read_only(tmp_path / 'out'):
    status, errout = _cli(monkeypatch, capsys, eval_script.main, *_flags(finished_run, scene_dir,
                                                                         f"Config.output_dir = '{tmp_path / 'out'}'"))
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, f"Config.output_dir {str(tmp_path / 'out')!r} cannot be written",
                  'expected a writable folder')


def test_a_read_only_checkpoints_folder_is_named_before_training(tmp_path, scene_dir, monkeypatch, capsys):
  run = tmp_path / 'run'
  loop.train(tiny_config(scene_dir, run, 'Config.max_steps = 4'), stop_at_step=2)
  capsys.readouterr()
  with read_only(run / 'checkpoints'):
    status, errout = _cli(monkeypatch, capsys, train_script.main, *TINY, f"Config.data_dir = '{scene_dir}'",
                          f"Config.checkpoint_dir = '{run}'", 'Config.max_steps = 4')
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, f"{str(run / 'checkpoints')!r} in Config.checkpoint_dir cannot be written",
                  'expected a writable folder')
  assert 'Traceback' not in errout and 'never awaited' not in errout and 'step/s' not in errout  # No step ran.
  with read_only(run / 'checkpoints'):
    status, errout = _cli(monkeypatch, capsys, train_script.main, *TINY, f"Config.data_dir = '{scene_dir}'",
                          f"Config.checkpoint_dir = '{run}'", 'Config.max_steps = 5', 'Config.overwrite = True')
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, f'Config.checkpoint_dir {str(run)!r} cannot be written', str(run / 'checkpoints'))
  assert sorted(os.listdir(run / 'checkpoints')) == ['2'] and (run / 'config.json').exists()
