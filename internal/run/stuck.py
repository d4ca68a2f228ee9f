"""Stuck training: a loss that sets no new best for a while early in a run and either never learned (e.g. a learning
rate so large that the network died and renders one colour), or learned and then died (flat well above its best),
or has since diverged, which would otherwise train to the end without a word. A plateau after the loss fell
(normal while FreeNeRF's frequency band opens: within a few percent of its best) is not stuck."""

import math

RELATIVE_IMPROVEMENT = 1e-3  # A window improves on the best loss when it is lower by more than this fraction.
EARLY_FACTOR = 4  # Only the first EARLY_FACTOR * patience steps are watched: later plateaus are normal.
MIN_WINDOWS = 4  # A patience scaled to a short run spans at least this many logged windows (noise of one window).
LEARNED_FRACTION = 0.5  # A run whose best loss is below this fraction of its first window's has learned something,
DIVERGED_FACTOR = 2.  # and is stuck only once its loss rose above this multiple of the best (or is not finite),
RISEN_FACTOR = 1.25  # or stayed above this multiple of it for the last patience steps (died after learning).


def patience(config) -> int:
  """Steps without a new best that count as stuck (0 = off): Config.stuck_warning_steps, or, in a run shorter than
  the EARLY_FACTOR x as many steps it would watch, a 1 / EARLY_FACTOR of the run (at least MIN_WINDOWS windows of
  Config.print_every steps), so that a network that died early is named in short runs too."""
  if config.stuck_warning_steps <= 0:
    return 0
  scaled = max(config.max_steps // EARLY_FACTOR, MIN_WINDOWS * config.print_every)
  return min(config.stuck_warning_steps, scaled)


def is_stuck(windows, patience: int) -> bool:
  """Windows [(end step, mean loss), ...] in step order -> True when none improved on the best for patience steps.

  The best is the lowest loss so far (non-finite means never improve); patience 0 turns the check off, and a last
  window past step EARLY_FACTOR * patience is no longer early, so never stuck. A run that learned (best below
  LEARNED_FRACTION of the first finite loss) is stuck only when its last loss is DIVERGED_FACTOR above the best,
  or every loss of its last patience steps RISEN_FACTOR above it.
  """
  if patience <= 0 or not windows or windows[-1][0] > EARLY_FACTOR * patience:
    return False
  best, best_step = math.inf, windows[0][0]
  for step, loss in windows:
    if math.isfinite(loss) and loss < best * (1. - RELATIVE_IMPROVEMENT):
      best, best_step = loss, step
  if windows[-1][0] - best_step < patience:
    return False
  first = next((loss for _, loss in windows if math.isfinite(loss)), math.inf)
  last = windows[-1][1]
  recent = [loss for step, loss in windows if step > windows[-1][0] - patience]  # All after the best.
  learned = best < LEARNED_FRACTION * first
  died = all(not loss <= RISEN_FACTOR * best for loss in recent)  # NaN counts as above.
  return not learned or not math.isfinite(last) or last > DIVERGED_FACTOR * best or died


def warning(config, windows) -> str:
  """The one-line warning about a stuck run whose window losses are windows, naming Config.lr_init."""
  best = min((loss for _, loss in windows if math.isfinite(loss)), default=math.nan)
  return (f'warning: the training loss set no new best for {patience(config)} steps (best {best:.4g}, '
          f'now {windows[-1][1]:.4g} at step {windows[-1][0]}): the network may be dead or diverging; check '
          f'Config.lr_init = {config.lr_init:g} (Config.stuck_warning_steps = 0 silences this)')
