"""Unhandled inputs and faults: each is a one-line user error naming the setting or file, or behaves correctly."""

import errno
import logging
import os
import pathlib
import re
import shutil
import struct
import subprocess
import zlib

import gin
import jax
import numpy as np
import pytest

import eval as eval_script
import render as render_script
import train as train_script
from internal import atomic
from internal import cli
from internal import rays as rays_lib
from internal.datasets import image_io
from internal.evaluation import inference
from internal.training import checkpoints
from internal.training import loop
from internal.training import memory
from internal.training import stuck
from internal.training import train_step
from internal.training import run_dir as run_dir_lib
from conftest import random_rays
from test_checkpoints import DEMO, TINY, tiny_config


def _cli(monkeypatch, capsys, main, *argv) -> tuple:
  """(exit status, stderr) of a script's main(argv) run as its command line runs it."""
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  gin.clear_config()  # As in a new process.
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


def test_zero_render_path_frames_is_refused_naming_the_setting():
  with pytest.raises(ValueError, match=r'Config\.render_path_frames = 0; expected a positive integer'):
    tiny_config('s', 'run', 'Config.render_path_frames = 0')


def _write_png16(path, values: np.ndarray) -> None:
  """Writes uint16 [H,W] (grey) or [H,W,4] (RGBA) as a 16-bit PNG, encoded here (Pillow writes no 16-bit RGBA)."""
  color_type = {2: 0, 3: 6}[values.ndim]
  height, width = values.shape[:2]
  raw = b''.join(b'\x00' + values[y].astype('>u2').tobytes() for y in range(height))  # Filter 0 per row.
  chunk = lambda kind, data: (struct.pack('>I', len(data)) + kind + data +
                              struct.pack('>I', zlib.crc32(kind + data) & 0xffffffff))
  header = struct.pack('>IIBBBBB', width, height, 16, color_type, 0, 0, 0)
  pathlib.Path(path).write_bytes(b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', header) + chunk(b'IDAT', zlib.compress(raw)) +
                                 chunk(b'IEND', b''))


def test_a_16_bit_grey_png_reads_at_its_full_depth(tmp_path):
  offsets = 100 * np.arange(1, 25)
  grey = (27 * 257 + np.concatenate([offsets, -offsets]).reshape(6, 8)).astype(np.uint16)  # Mean 27/255.
  _write_png16(tmp_path / 'grey.png', grey)
  expected = grey.astype(np.float64) / 65535.
  rgb = image_io.load_rgb(str(tmp_path / 'grey.png'), 1, 'released')
  assert rgb.shape == (6, 8, 3) and abs(rgb.mean() - 27 / 255) < 1e-6
  np.testing.assert_allclose(rgb, np.repeat(expected[..., None], 3, -1), atol=1e-6)
  rgba = image_io.load_rgba(str(tmp_path / 'grey.png'), 1, 'released')
  np.testing.assert_allclose(rgba[..., :3], rgb)
  np.testing.assert_array_equal(rgba[..., 3], 1.)


def test_a_16_bit_rgba_png_reads_at_its_full_depth(tmp_path):
  rgba = np.random.default_rng(1).integers(0, 65536, (6, 8, 4)).astype(np.uint16)
  _write_png16(tmp_path / 'rgba.png', rgba)
  read = image_io.read_image(str(tmp_path / 'rgba.png'), 'RGBA')
  np.testing.assert_allclose(read, rgba / 65535., atol=1e-7)  # Within float32 rounding, not 1/255.
  assert read.dtype == np.float32 and read.max() <= 1.
  np.testing.assert_allclose(image_io.read_image(str(tmp_path / 'rgba.png'), 'RGB'), rgba[..., :3] / 65535.,
                             atol=1e-7)
  luma = image_io.read_image(str(tmp_path / 'rgba.png'), 'L')[..., 0]
  np.testing.assert_allclose(luma, rgba[..., :3] @ [0.299, 0.587, 0.114] / 65535., atol=1e-6)


def test_a_truncated_16_bit_png_is_named(tmp_path):
  _write_png16(tmp_path / 'rgba.png', np.zeros((6, 8, 4), np.uint16))
  data = (tmp_path / 'rgba.png').read_bytes()
  (tmp_path / 'rgba.png').write_bytes(data[:60])
  with pytest.raises(image_io.DatasetError, match="cannot read image .*rgba.png"):
    image_io.read_image(str(tmp_path / 'rgba.png'))


def test_stuck_detector_on_flat_falling_and_late_losses():
  flat = [(step, 0.5 + 0.01 * ((step // 10 - 1) % 3)) for step in range(10, 80, 10)]  # Best 0.5 at step 10, tied.
  assert not stuck.is_stuck(flat[:5], 50) and stuck.is_stuck(flat[:6], 50)  # Steps 10 -> 60: 50 without a best.
  falling = [(step, 1. / step) for step in range(10, 200, 10)]
  assert not stuck.is_stuck(falling, 50)
  tiny_gain = [(step, 0.5 * (1. - 1e-4 * step / 10)) for step in range(10, 80, 10)]  # 5e-4 in 50 steps.
  assert stuck.is_stuck(tiny_gain, 50)
  assert not stuck.is_stuck(flat, 0)  # Off.
  assert not stuck.is_stuck(flat + [(210, 0.5)], 50)  # Past 4 x 50 steps: no longer early.
  assert stuck.is_stuck([(step, float('nan')) for step in (10, 30, 60)], 50)  # Non-finite never improves.


def test_a_huge_learning_rate_warns_once_naming_lr_init(tmp_path, scene_dir, capsys):
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.lr_init = 1e4', 'Config.lr_final = 1e4',
                       'Config.max_steps = 60', 'Config.stuck_warning_steps = 15')
  loop.train(config)
  out = capsys.readouterr().out
  assert out.count('warning: the training loss set no new best for 15 steps') == 1, out
  assert 'Config.lr_init = 10000' in out


def _out_of_memory(*args):
  """What jax raises when XLA cannot allocate device memory."""
  raise jax.errors.JaxRuntimeError('RESOURCE_EXHAUSTED: Out of memory while trying to allocate 123456789 bytes.\n'
                                   'BufferAssignment OOM Debugging.')


class _FailingStep:
  """A compiled training step that runs out of memory when called; it lowers (for XLA's estimate) as the real one."""

  def __init__(self, step_fn):
    self.lower = step_fn.lower

  __call__ = staticmethod(_out_of_memory)


def test_a_training_step_out_of_memory_names_batch_size_and_xla_estimate(tmp_path, scene_dir, monkeypatch,
                                                                           capsys):
  make_step = train_step.make_train_step
  monkeypatch.setattr(train_step, 'make_train_step', lambda config, model: _FailingStep(make_step(config, model)))
  status, errout = _cli(monkeypatch, capsys, train_script.main, *TINY, f"Config.data_dir = '{scene_dir}'",
                        f"Config.checkpoint_dir = '{tmp_path / 'run'}'")
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, 'out of accelerator memory in the training step', 'Out of memory while trying to allocate',
                  'lower Config.batch_size = 128')
  estimate = float(re.search(r'XLA estimates ([0-9.]+) MiB', errout).group(1)) * memory.MIB
  config = tiny_config(scene_dir, tmp_path / 'other')
  _, state = train_step.create_train_state(config, jax.random.PRNGKey(0), random_rays(0, 8))
  state_bytes = sum(x.nbytes for x in jax.tree.leaves(state))  # Parameters and Adam moments, in and out.
  assert 2 * state_bytes <= estimate < 2 * state_bytes + 64 * memory.MIB, (state_bytes, estimate)


def test_bugs_of_xla_that_are_not_out_of_memory_keep_their_traceback(monkeypatch):
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  def failing():
    raise jax.errors.JaxRuntimeError('INTERNAL: something else')
  with pytest.raises(jax.errors.JaxRuntimeError):
    cli.run(failing)


def test_rendering_out_of_memory_names_render_chunk_size(monkeypatch, capsys):
  rays = rays_lib.map_rays(lambda x: x.reshape(2, 3, -1), random_rays(0, 6))
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  assert cli.run(lambda: inference.render_image(_out_of_memory, rays, 4)) == cli.USAGE_ERROR_STATUS
  _one_error_line(capsys.readouterr().err, 'out of accelerator memory rendering', 'Config.render_chunk_size = 4')


def test_disk_full_errors_are_recognised_bare_and_as_orbax_wraps_them():
  assert checkpoints.is_disk_full(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), 'x'))
  assert checkpoints.is_disk_full(ValueError(
      'RESOURCE_EXHAUSTED: Error writing "params.w/0" in OCDBT database at local file "/r/checkpoints/2.orbax-'
      'checkpoint-tmp/": Failed to write 199981 bytes to file 5: No space left on device [os_error_code=\'28\']'))
  assert not checkpoints.is_disk_full(OSError(errno.EACCES, os.strerror(errno.EACCES)))
  assert not checkpoints.is_disk_full(ValueError('RESOURCE_EXHAUSTED: Out of memory'))


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
