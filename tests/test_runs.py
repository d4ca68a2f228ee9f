"""The door to runs (internal/runs.py): a Config parsed afresh with gin cleared before and after, a run folder's own
Config, and the flags of every script and tool through it."""

import os

import gin
import pytest

from internal import cli
from internal import runs
from internal.models import mip_nerf
from test_checkpoints import DEMO, TINY, tiny_config


def _bound(name: str):
  """The value gin binds to name, None when nothing binds it."""
  try:
    return gin.query_parameter(name)
  except ValueError:
    return None


def test_fresh_config_clears_gin_before_and_after_the_block():
  gin.parse_config(['MLP.density_noise = 3.0'])  # Another Config's setting, left behind.
  with runs.fresh_config([DEMO], ['MLP.net_width = 8']) as config:
    assert _bound('MLP.density_noise') is None and mip_nerf.MLP().net_width == 8  # The model reads its own.
    assert config.checkpoint_dir == 'out/demo/freenerf'
  assert _bound('MLP.net_width') is None


def test_fresh_config_clears_gin_after_a_failing_block_and_a_bad_setting():
  with pytest.raises(RuntimeError):
    with runs.fresh_config([], ['MLP.net_width = 8']):
      raise RuntimeError('the block failed')
  assert _bound('MLP.net_width') is None
  with pytest.raises(ValueError, match='Config.precrop_frac'):
    with runs.fresh_config([], ['MLP.net_width = 8', 'Config.precrop_frac = 0.']):
      pass
  assert _bound('MLP.net_width') is None
  with runs.fresh_config([], ['MLP.net_width = 9']):  # gin is not left locked by the failed parse.
    assert mip_nerf.MLP().net_width == 9


def test_bind_fresh_leaves_gin_bound_to_its_config_until_the_next():
  runs.bind_fresh([], ['MLP.net_width = 8'])
  assert mip_nerf.MLP().net_width == 8
  runs.bind_fresh([], ['MLP.density_noise = 3.0'])
  assert _bound('MLP.net_width') is None and _bound('MLP.density_noise') == 3.0


def test_run_config_is_the_config_a_run_folder_recorded(scene_dir, tmp_path):
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.max_steps = 2', 'Config.checkpoint_every = 2')
  runs.train(config)
  with runs.run_config(str(tmp_path / 'run')) as recorded:
    assert recorded.max_steps == 2 and recorded.data_dir == str(scene_dir)
    assert runs.differences(runs.read_fingerprint(str(tmp_path / 'run')), recorded) == ''
  assert runs.latest_step(str(tmp_path / 'run')) == 2 and runs.latest_step(str(tmp_path)) is None
  missing = os.path.join(str(tmp_path), 'config.gin')
  with pytest.raises(FileNotFoundError, match=f"'{missing}' does not exist; expected a run folder"):
    with runs.run_config(str(tmp_path)):
      pass


def test_a_scripts_flags_bind_gin_afresh():
  """train.py, eval.py, render.py and the tools read their Config through cli.config_from_flags: a binding another
  Config left in this process does not reach it."""
  gin.parse_config(['MLP.density_noise = 3.0'])
  args = cli.flag_parser('test').parse_args(['--gin_configs', DEMO, '--gin_bindings', *TINY])
  config = cli.config_from_flags(args)
  assert _bound('MLP.density_noise') is None and mip_nerf.MLP().net_depth == 2 and config.max_steps == 700
