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


def test_a_plateau_after_learning_is_not_stuck_but_divergence_is():
  # The window losses of a healthy DTU FreeNeRF run on a GPU (3100 steps, patience 500), which once warned: the loss
  # fell 9x, then sat at 0.031-0.032 for 500 steps while the frequency band opened.
  healthy = [(300, .2881), (500, .1642), (700, .0719), (900, .0522), (1100, .0416), (1300, .0360), (1400, .0311),
             (1500, .0311), (1700, .0322), (1900, .0321), (2000, .0320)]
  assert not stuck.is_stuck(healthy, 500)
  assert stuck.is_stuck(healthy + [(2000, .0700)], 500)  # Rose above twice the best: diverging.
  assert stuck.is_stuck(healthy + [(2000, float('nan'))], 500)
  barely = [(step, 0.3 - 1e-4 * step / 100) for step in range(100, 700, 100)] + [(1000, 0.2997)]
  assert stuck.is_stuck(barely, 500)  # Never learned: best above half the first loss.


def test_a_run_that_learns_then_dies_flat_above_its_best_is_stuck():
  # 0.30 -> 0.10 by step 700, then dead: flat at 0.16 (a constant colour's loss), well above the best but below twice.
  died = [(100, .30), (300, .20), (500, .13), (700, .10)] + [(step, .16) for step in range(800, 1300, 100)]
  assert not stuck.is_stuck(died[:-1], 500)  # Step 1100: only 400 steps since the best.
  assert stuck.is_stuck(died, 500)  # Step 1200: 500 steps without a new best, all of them 1.6 x the best.
  plateau = died[:4] + [(step, .115) for step in range(800, 1300, 100)]  # 15% above the best: a plateau.
  assert not stuck.is_stuck(plateau, 500)
  recovering = died[:-1] + [(1200, .11)]  # Falling back towards its best: not dead.
  assert not stuck.is_stuck(recovering, 500)



def test_a_huge_learning_rate_warns_once_naming_lr_init(tmp_path, scene_dir, capsys):
  config = tiny_config(scene_dir, tmp_path / 'run', 'Config.lr_init = 1e4', 'Config.lr_final = 1e4',
                       'Config.max_steps = 60', 'Config.stuck_warning_steps = 15')
  loop.train(config)
  out = capsys.readouterr().out
  assert out.count('warning: the training loss set no new best for 15 steps') == 1, out
  assert 'Config.lr_init = 10000' in out
