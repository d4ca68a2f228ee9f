"""The stuck-training warning: the detector on loss histories, and one warning naming Config.lr_init."""

from internal.pipeline import loop
from internal.run import stuck
from test_checkpoints import tiny_config


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
