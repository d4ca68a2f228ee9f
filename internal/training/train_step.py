"""One jit-compiled, pure training step: masks, losses, clipping, Adam, non-finite guard."""

import functools
import re
from typing import Any

import flax
import jax
import jax.numpy as jnp
from jax import random
import numpy as np
import optax

from internal.datasets import batching
from internal.losses import reconstruction
from internal.losses import terms
from internal.models import freq_schedule
from internal.models import registry
from internal.training import camera_refinement
from internal.training import optim
from internal.training import renderer
from internal.training import schedule


@flax.struct.dataclass
class TrainState:
  """Parameters and optimizer state after `step` updates."""
  step: jax.Array
  params: Any
  opt_state: Any


@flax.struct.dataclass
class CameraTrainState(TrainState):
  """A TrainState that also refines the training cameras (Config.optimize_cameras): camera_refinement.CameraState."""
  cameras: Any


NONFINITE_POLICIES = ('skip', 'raise')  # Config.nonfinite_grad_policy: see SkipCounter.


class NonFiniteError(FloatingPointError):
  """A step's loss, gradients, learning rate or update was not finite (policy 'raise' or too many skips)."""


# What the guard checks, as (stats flag, words for the error message): an update is skipped unless all hold.
GUARD_CHECKS = (('loss_finite', 'loss'), ('grads_finite', 'gradients'),
                ('lr_valid', 'learning rate (Config.lr_init, lr_final, lr_delay_mult)'),
                ('update_finite', 'new parameters / optimizer state'))
# What a skipped step's message names before them, in the order the step computes it: the batch's inputs (stats
# flags: the batch's Rays, under keys ending in 'rays', and its other arrays), then each loss term (LOSS_TERMS).
INPUT_CHECKS = (('rays_finite', 'rays of the batch (the training cameras)'),
                ('targets_finite', 'targets of the batch (colours of the images, depth priors)'))
# The loss terms of stats in the order compute_loss adds them, with the Config setting that weights each ('' =
# none): the data loss and weight decay, then the regularizers' table (losses/terms.py); a name ending in 'level'
# is one term per level, every level but the last weighted by coarse_loss_mult. A weighted term's stats flag
# '<term>_weighted_finite' says whether it times its weight is finite, so that a message names the weight whose
# size made a finite term overflow.
LOSS_TERMS = (('loss_level', ''), ('weight_l2', 'weight_decay_mult')) + tuple(
    (term.stats, term.weight) for term in terms.TERMS)


def create_train_state(config, key, example_rays, cameras=None):
  """(model, TrainState at step 0) for Config, initialized on example rays [B, ...]; with a CameraState (camera
  refinement) a CameraTrainState."""
  model, variables = registry.construct_model(config.model, key, example_rays, config.white_background,
                                             config.precision)
  params = variables['params']
  state = TrainState(step=jnp.array(0, jnp.int32), params=params,
                     opt_state=jax.jit(optim.adam(config.adam_eps).init)(params))
  if cameras is not None:
    state = CameraTrainState(step=state.step, params=state.params, opt_state=state.opt_state, cameras=cameras)
  return model, state


def compute_loss(config, model, params, batch: batching.Batch, key, step):
  """(total loss, stats) of one Batch at step: every ray family of the batch rendered once (training/renderer.py),
  the data loss of the training pixels per level (the coarse ones times Config.coarse_loss_mult), weight decay and
  each term of losses/terms.TERMS that is on, in its order; every term's value also goes into stats."""
  masks = freq_schedule.model_masks(config, model, step)
  rendered = renderer.render_batch(config, model, params, batch, key, step, masks)
  pixels = rendered['rays']
  stats = {}
  level_losses = []
  for level, rendering in enumerate(pixels.levels):
    level_losses.append(reconstruction.data_loss(rendering['rgb'], batch.rgb, pixels.rays.lossmult))
    stats[f'loss_level{level}'] = level_losses[-1]
    stats[f'psnr_level{level}'] = reconstruction.true_psnr(rendering['rgb'], batch.rgb, pixels.rays.lossmult)
  loss = level_losses[-1] + config.coarse_loss_mult * sum(level_losses[:-1])
  stats['weight_l2'] = reconstruction.weight_l2(params)
  loss += config.weight_decay_mult * stats['weight_l2']
  for term in terms.TERMS:
    if term.is_on(config):
      value, term_stats = term.loss(config, rendered, batch, step)
      stats.update(term_stats)
      loss += value
  if masks[0] is not None:
    stats['mask_visible_point'] = jnp.mean(masks[0])
    stats['mask_visible_view'] = jnp.mean(masks[1])
  stats['loss'] = loss
  stats['psnr'] = stats[f'psnr_level{len(pixels.levels) - 1}']
  return loss, stats


def _input_flags(batch: batching.Batch) -> dict:
  """INPUT_CHECKS' flags of a batch: whether its Rays (every family's), and its other arrays (the targets, not the
  pixels), are finite."""
  fields = batch._asdict()
  rays = [name for name, _ in batching.FAMILIES]
  pixels = [name for _, name in batching.FAMILIES if name]
  return {'rays_finite': optim.all_finite([fields[name] for name in rays]),
          'targets_finite': optim.all_finite([v for k, v in fields.items() if k not in rays + pixels])}


def loss_terms(stats) -> list:
  """(stats key, weighting Config setting or '') of each loss term in stats, in the order compute_loss adds them."""
  found = []
  for name, setting in LOSS_TERMS:
    if not name.endswith('level'):
      found += [(name, setting)] if name in stats else []
      continue
    levels = sorted((k for k in stats if re.fullmatch(rf'{name}\d+', k)), key=lambda k: int(k[len(name):]))
    found += [(k, 'coarse_loss_mult' if i < len(levels) - 1 else setting) for i, k in enumerate(levels)]
  return found


def _weighted_term_flags(config, stats, step) -> dict:
  """'<term>_weighted_finite' of each weighted loss term of stats: whether it times its weight at step is finite."""
  scheduled = {term.weight: term.weight_at for term in terms.TERMS if term.weight_at is not None}
  weight = lambda setting: scheduled[setting](config, step) if setting in scheduled else getattr(config, setting)
  return {f'{key}_weighted_finite': jnp.isfinite(weight(setting) * stats[key])
          for key, setting in loss_terms(stats) if setting}


def make_train_step(config, model):
  """jit-compiled (state, batch, key) -> (state, stats); step t = state.step + 1 drives mask and lr."""
  adam = optim.adam(config.adam_eps)

  def train_step(state, batch, key):
    step = state.step + 1
    loss_fn = functools.partial(compute_loss, config, model)
    cameras = getattr(state, 'cameras', None)
    if cameras is None:
      (loss, stats), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, batch,
                                                                        random.fold_in(key, step), step)
      camera_grads = None
    else:  # The batch's rays made from the corrected cameras; the corrections get their own gradient.
      (loss, stats), (grads, camera_grads) = camera_refinement.value_and_grads(
          loss_fn, state.params, cameras, batch, random.fold_in(key, step), step)
    stats.update(_input_flags(batch), **_weighted_term_flags(config, stats, step))
    stats.update(loss_finite=jnp.isfinite(loss), grads_finite=optim.all_finite((grads, camera_grads)))
    grads, clip_stats = optim.clip_gradients(grads, config.grad_max_val, config.grad_max_norm)
    lr = schedule.config_learning_rate(config, step)
    updates, opt_state = adam.update(grads, state.opt_state, state.params)
    params = optax.apply_updates(state.params, jax.tree.map(lambda u: -lr * u, updates))
    if cameras is not None:
      cameras, camera_stats = camera_refinement.update(config, cameras, camera_grads, step)
      stats.update(camera_stats)
    stats.update(lr_valid=jnp.isfinite(lr) & (lr > 0), update_finite=optim.all_finite((params, opt_state, cameras)))
    ok = jnp.all(jnp.array([stats[flag] for flag, _ in GUARD_CHECKS]))
    # A skipped step still advances state.step: the batch and key of step t depend on t only, so a resumed
    # run replays exactly the same steps, skipped ones included.
    keep = lambda new, old: jax.tree.map(lambda n, o: jnp.where(ok, n, o), new, old)
    stats.update(clip_stats, lr=lr, skipped=~ok)
    new_state = state.replace(step=step, params=keep(params, state.params),
                              opt_state=keep(opt_state, state.opt_state))
    if cameras is not None:
      new_state = new_state.replace(cameras=keep(cameras, state.cameras))
    return new_state, stats

  return jax.jit(train_step, donate_argnums=(0,))


def nonfinite_quantities(stats) -> list:
  """Words for each checked quantity of a step's (host) stats that is not finite (or, the learning rate, not
  positive), in the order the step computes them: a loss term finite only before its weight names the weight."""
  found = [words for flag, words in INPUT_CHECKS if flag in stats and not bool(stats[flag])]
  for key, setting in loss_terms(stats):
    if not np.isfinite(stats[key]):
      found.append(key)
    elif not bool(stats.get(f'{key}_weighted_finite', True)):
      found.append(f'{key} x its weight Config.{setting}')
  return found + [words for flag, words in GUARD_CHECKS if not bool(stats[flag])]


def skip_reason(stats) -> str:
  """The first quantity of a step's (host) stats that was not finite, in the step's order, then the guarded
  values that followed it, in words."""
  first, *later = nonfinite_quantities(stats)
  after = [words for _, words in GUARD_CHECKS if words in later]
  return ', then '.join([first, ', '.join(after)] if after else [first])


class SkipCounter:
  """Host-side count of skipped updates (all and consecutive); raises NonFiniteError as Config asks."""

  def __init__(self, policy: str, max_skipped_steps: int):
    self.policy, self.max_skipped_steps = policy, max_skipped_steps
    self.total = self.streak = 0

  def record(self, stats, step: int) -> None:
    """Counts step's (host) stats; NonFiniteError under policy 'raise' or after max_skipped_steps in a row."""
    if not bool(stats['skipped']):
      self.streak = 0
      return
    self.total += 1
    self.streak += 1
    if self.policy == 'raise':
      raise NonFiniteError(
          f'step {step}: non-finite {skip_reason(stats)} (update skipped, parameters unchanged); '
          "set Config.nonfinite_grad_policy = 'skip' to continue past such steps")
    if self.streak >= self.max_skipped_steps:
      raise NonFiniteError(
          f'steps {step - self.streak + 1}-{step}: {self.streak} consecutive updates skipped (last: non-finite '
          f'{skip_reason(stats)}), Config.max_skipped_steps = {self.max_skipped_steps}; the run cannot make '
          'progress: check the data and the learning-rate settings')
