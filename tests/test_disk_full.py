"""A full disk ends in one line and exit status 4: orbax's late reports of its failed writes print nothing."""

import asyncio
import errno
import gc
import logging
import os
import shutil
import subprocess
import sys
import types
import warnings

import jax
import numpy as np
import pytest

import train as train_script
from conftest import JAX_CACHE, random_rays
from internal import atomic
from internal import cli
from internal.run import checkpoints
from internal.run import disk_full
from internal.pipeline import loop
from orbax.checkpoint._src.path import async_path
from test_checkpoints import DEMO, ROOT, TINY, tiny_config
from test_run_dir_errors import _cli, _one_error_line

NO_SPACE = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_orbax_reports_after_a_failed_save_are_dropped_and_others_kept(tmp_path, monkeypatch, capsys):
  passed_on = []
  monkeypatch.setattr(sys, 'unraisablehook', passed_on.append)
  asyncio_logger = logging.getLogger('asyncio')
  monkeypatch.setattr(asyncio_logger, 'filters', [])
  records = []
  handler = logging.Handler()
  handler.emit = records.append
  asyncio_logger.addHandler(handler)
  try:
    with pytest.raises(disk_full.DiskFullError, match='no space left on the device while saving'):
      with disk_full.stop_when_disk_full(str(tmp_path)):
        raise NO_SPACE
    # What orbax's abandoned writes report later: a future never retrieved, callbacks into its closed loop.
    asyncio_logger.error('Future exception was never retrieved', exc_info=_orbax_write_on_a_full_disk())
    asyncio_logger.error('Task exception was never retrieved: something else')
    asyncio_logger.error('Future exception was never retrieved', exc_info=(OSError, NO_SPACE, None))  # Not orbax's.
    for place in (tmp_path / 'checkpoints' / '6.orbax-checkpoint-tmp', tmp_path / 'elsewhere'):  # Tensorstore's:
      failed = ValueError(f'RESOURCE_EXHAUSTED: Error writing "step/0" in OCDBT database at local file "{place}/": '
                          f"Failed to write: No space left on device [os_error_code='{errno.ENOSPC}']")
      asyncio_logger.error('Future exception was never retrieved', exc_info=(ValueError, failed, None))
    closed = types.SimpleNamespace(exc_value=RuntimeError('Event loop is closed'), object=None)
    other = types.SimpleNamespace(exc_value=RuntimeError('a bug'), object=None)
    sys.unraisablehook(closed)
    sys.unraisablehook(other)
  finally:
    asyncio_logger.removeHandler(handler)
  assert [r.getMessage() for r in records] == ['Task exception was never retrieved: something else',
                                               'Future exception was never retrieved',
                                               'Future exception was never retrieved']
  assert records[1].exc_info[1] is NO_SPACE and 'elsewhere' in str(records[2].exc_info[1])
  assert passed_on == [other]


class _FullDiskPath:
  """A path whose writes find the disk full."""

  def unlink(self):
    pass

  def write_bytes(self, data):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), 'x')


def _orbax_write_on_a_full_disk() -> tuple:
  """exc_info of one of orbax's writes (its write_bytes) that found the disk full."""
  try:
    asyncio.run(async_path.write_bytes(_FullDiskPath(), b'x'))
  except OSError as err:
    return type(err), err, err.__traceback__
  raise AssertionError('the write did not fail')


def test_the_filters_go_when_training_ends_without_a_full_disk(tmp_path, monkeypatch):
  hook = sys.unraisablehook
  monkeypatch.setattr(logging.getLogger('asyncio'), 'filters', [])
  with pytest.raises(KeyError):
    with disk_full.stop_when_disk_full(str(tmp_path)):
      raise KeyError('a bug')
  assert sys.unraisablehook is hook and not logging.getLogger('asyncio').filters


async def _not_orbax():
  """A coroutine of something else than orbax."""


def _unawaited_warnings(full: bool) -> list:
  """The 'never awaited' warnings of one of orbax's write coroutines and of another one, both dropped unawaited
  after a block that raised ENOSPC (or a KeyError)."""
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    with pytest.raises(disk_full.DiskFullError if full else KeyError):
      with disk_full.stop_when_disk_full('run'):
        raise NO_SPACE if full else KeyError('a bug')
    async_path.write_bytes('run/checkpoints/3.orbax-checkpoint-tmp/x', b'')  # Created and dropped, never awaited.
    _not_orbax()
    gc.collect()
  return sorted(str(w.message) for w in caught if 'was never awaited' in str(w.message))


def test_unawaited_orbax_writes_are_silent_after_a_full_disk_and_others_are_reported(monkeypatch):
  monkeypatch.setattr(sys, 'unraisablehook', sys.unraisablehook)
  monkeypatch.setattr(logging.getLogger('absl'), 'filters', [])
  monkeypatch.setattr(logging.getLogger('asyncio'), 'filters', [])
  both = ["coroutine '_not_orbax' was never awaited", "coroutine 'write_bytes' was never awaited"]
  assert _unawaited_warnings(full=False) == both
  assert _unawaited_warnings(full=True) == both[:1]  # Only the failed save's own coroutine is silent.


def test_a_full_disk_while_writing_a_settings_file_is_one_line_naming_it(tmp_path, monkeypatch, capsys):
  def no_space(fd):
    raise NO_SPACE
  monkeypatch.setattr(os, 'fsync', no_space)
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  assert cli.run(lambda: atomic.write_text(tmp_path / 'config.gin', 'text')) == cli.DISK_FULL_STATUS
  assert capsys.readouterr().err == (f"error: no space left on the device writing {str(tmp_path / 'config.gin')!r}; "
                                     'free disk space and run the same command again\n')
  assert os.listdir(tmp_path) == []


def _train_script(run, scene_dir, *bindings, timeout: float) -> subprocess.CompletedProcess:
  """train.py on the tiny demo config in run; a hang longer than timeout seconds fails the test (TimeoutExpired)."""
  env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=JAX_CACHE, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0')
  env.pop(cli.DEBUG_ENV, None)
  return subprocess.run([sys.executable, 'train.py', '--gin_configs', DEMO, '--gin_bindings', *TINY, *bindings,
                         f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'"], cwd=ROOT, env=env,
                        capture_output=True, text=True, check=False, timeout=timeout)


def test_a_full_disk_during_a_save_prints_no_traceback(small_disk, scene_dir):
  run = small_disk / 'run'
  bindings = ['Config.max_steps = 6', 'Config.checkpoint_every = 3']
  loop.train(tiny_config(scene_dir, run, *bindings), stop_at_step=3)
  checkpoint_bytes = sum(f.stat().st_size for f in (run / 'checkpoints' / '3').rglob('*') if f.is_file())
  free = shutil.disk_usage(small_disk).free
  (small_disk / 'filler').write_bytes(b'\1' * (free - checkpoint_bytes // 2))  # Room for half a checkpoint.
  done = _train_script(run, scene_dir, *bindings, timeout=180)
  assert done.returncode == cli.DISK_FULL_STATUS, done.stderr[-3000:]
  assert 'Traceback' not in done.stderr and 'ERROR' not in done.stderr, done.stderr[-3000:]
  last = done.stderr.strip().splitlines()[-1]
  assert last.startswith('error: no space left on the device while saving a checkpoint'), done.stderr[-3000:]
  assert 'step 3, is kept' in last


def test_disk_full_errors_are_recognised_bare_and_as_orbax_wraps_them():
  assert disk_full.is_disk_full(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), 'x'))
  assert disk_full.is_disk_full(ValueError(
      'RESOURCE_EXHAUSTED: Error writing "params.w/0" in OCDBT database at local file "/r/checkpoints/2.orbax-'
      'checkpoint-tmp/": Failed to write 199981 bytes to file 5: No space left on device [os_error_code=\'28\']'))
  assert not disk_full.is_disk_full(OSError(errno.EACCES, os.strerror(errno.EACCES)))
  assert not disk_full.is_disk_full(ValueError('RESOURCE_EXHAUSTED: Out of memory'))



@pytest.fixture
def small_disk(tmp_path):
  """A 32 MiB tmpfs mounted at tmp_path/disk, unmounted afterwards; skips where mounting is not allowed."""
  disk = tmp_path / 'disk'
  disk.mkdir()
  mount = subprocess.run(['mount', '-t', 'tmpfs', '-o', 'size=32m', 'tmpfs', str(disk)], capture_output=True,
                         text=True, check=False)
  if mount.returncode:
    pytest.skip(f'cannot mount a small tmpfs here (needs root): {mount.stderr.strip()}')
  yield disk
  subprocess.run(['umount', str(disk)], check=True)



def test_a_checkpoint_save_on_a_full_disk_keeps_the_previous_one_and_exits_4(small_disk, scene_dir, monkeypatch,
                                                                              capsys, caplog):
  bindings = (f"Config.checkpoint_dir = '{small_disk / 'run'}'", 'Config.max_steps = 6', 'Config.checkpoint_every = 3')
  first = loop.train(tiny_config(scene_dir, small_disk / 'run', *bindings[1:]), stop_at_step=3)
  kept = [np.asarray(x) for x in jax.tree.leaves(jax.device_get(first.state))]
  step_dir = small_disk / 'run' / 'checkpoints' / '3'
  checkpoint_bytes = sum(f.stat().st_size for f in step_dir.rglob('*') if f.is_file())
  filler = small_disk / 'filler'
  filler.write_bytes(b'\1' * (shutil.disk_usage(small_disk).free - checkpoint_bytes // 4))
  status, errout = _cli(monkeypatch, capsys, train_script.main, *TINY, f"Config.data_dir = '{scene_dir}'", *bindings)
  assert status == cli.DISK_FULL_STATUS == 4
  _one_error_line(errout, 'no space left on the device while saving a checkpoint',
                  'the newest intact checkpoint, step 3, is kept', 'run the same command again to resume')
  assert not [r for r in caplog.records if r.name == 'absl' and r.levelno >= logging.ERROR]  # Orbax's tracebacks.
  filler.unlink()
  assert checkpoints.latest_step(str(small_disk / 'run')) == 3
  config = tiny_config(scene_dir, small_disk / 'run', *bindings[1:])
  _, state = checkpoints.restore_model(config, str(small_disk / 'run'), random_rays(0, 8))
  for a, b in zip(kept, jax.tree.leaves(jax.device_get(state))):
    np.testing.assert_array_equal(a, b)


def test_tensorboard_events_on_a_full_disk_end_training_in_one_line_instead_of_a_hang(small_disk, scene_dir):
  # tensorboardX's writer thread died on the full disk and the loop waited for its queue forever.
  run = small_disk / 'run'
  bindings = ['Config.max_steps = 200', 'Config.checkpoint_every = 3']
  loop.train(tiny_config(scene_dir, run, *bindings), stop_at_step=3)
  # Room for the lock and the rewritten config.gin, not for a few previews' images in the event file.
  (small_disk / 'filler').write_bytes(b'\1' * (shutil.disk_usage(small_disk).free - 12288))
  done = _train_script(run, scene_dir, *bindings, 'Config.train_render_every = 1', timeout=180)
  assert done.returncode == cli.DISK_FULL_STATUS, done.stderr[-3000:]
  assert 'Traceback' not in done.stderr and 'ERROR' not in done.stderr, done.stderr[-3000:]
  _one_error_line(done.stderr, f"no space left on the device while writing '{run / 'tensorboard'}{os.sep}events.",
                  'the newest intact checkpoint, step 3, is kept', 'run the same command again to resume')
  (small_disk / 'filler').unlink()
  assert checkpoints.latest_step(str(run)) == 3


def test_a_full_disk_names_the_file_of_any_training_write(tmp_path):
  clock, folder = str(tmp_path / 'learning_curve_clock.json'), str(tmp_path / 'checkpoints')
  checkpoint = f'saving a checkpoint in {folder!r}'
  for written, said in [(clock, f'writing {clock!r}'), (folder + '/6.orbax-checkpoint-tmp/x', checkpoint),
                        (None, checkpoint)]:  # Orbax's errors name no file.
    with pytest.raises(disk_full.DiskFullError) as stopped:
      with disk_full.stop_when_disk_full(str(tmp_path)):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), *([written] if written else []))
    assert str(stopped.value).startswith(f'no space left on the device while {said}; no earlier checkpoint exists.')
