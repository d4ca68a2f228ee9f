"""Running out of accelerator memory is one line naming the setting to lower; other XLA errors keep their traceback."""

import re

import jax
import pytest

import train as train_script
from internal import cli
from internal import rays as rays_lib
from internal.evaluation import inference
from internal.run import out_of_memory
from internal.training import train_step
from conftest import random_rays
from test_checkpoints import TINY, tiny_config
from test_run_dir_errors import _cli, _one_error_line


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
  estimate = float(re.search(r'XLA estimates ([0-9.]+) MiB', errout).group(1)) * out_of_memory.MIB
  config = tiny_config(scene_dir, tmp_path / 'other')
  _, state = train_step.create_train_state(config, jax.random.PRNGKey(0), random_rays(0, 8))
  state_bytes = sum(x.nbytes for x in jax.tree.leaves(state))  # Parameters and Adam moments, in and out.
  assert 2 * state_bytes <= estimate < 2 * state_bytes + 64 * out_of_memory.MIB, (state_bytes, estimate)



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
