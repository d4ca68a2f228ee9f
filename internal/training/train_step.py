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

from internal.datasets import random_poses
from internal.models import freq_schedule
from internal.models import registry
from internal.losses import depth_smoothness
from internal.losses import occlusion
from internal.losses import reconstruction
from internal.training import anneal
from internal.training import camera_refinement
from internal.training import optim
from internal.training import schedule
from internal.training import prior_losses


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
# none); a name ending in 'level' is one term per level, every level but the last weighted by coarse_loss_mult.
# A weighted term's stats flag '<term>_weighted_finite' says whether it times its weight is finite, so that a
# message names the weight whose size made a finite term overflow.
LOSS_TERMS = (('loss_level', ''), ('weight_l2', 'weight_decay_mult'), ('loss_occ', 'occ_reg_loss_mult'),
              ('loss_distortion', 'distortion_loss_mult'), ('depth_tv_level', 'depth_tvnorm_loss_mult'),
              ('loss_depth_rank', 'depth_rank_loss_mult'), ('loss_depth_pearson', 'depth_pearson_loss_mult'),
              ('loss_sfm_depth', 'sfm_depth_loss_mult'))


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


def compute_loss(config, model, params, batch, key, step):
  """(total loss, stats) of one batch {'rays': Rays [B, ...], 'rgb': [B, 3]} at step.

  With RegNeRF's depth smoothness the batch also holds 'patch_rays' [P, ps, ps, ...] (no data loss on them).
  """
  mask_point, mask_view = freq_schedule.model_masks(config, model, step)
  rays = batch['rays']
  if config.anneal_nearfar:
    rays = anneal.anneal_rays(config, rays, step)
  renderings, history = model.apply(
      {'params': params}, key if config.randomized else None, rays, mask_point, mask_view,
      schedule.resample_padding(config, step))
  stats = {}
  level_losses = []
  for level, rendering in enumerate(renderings):
    level_losses.append(reconstruction.data_loss(rendering['rgb'], batch['rgb'], rays.lossmult))
    stats[f'loss_level{level}'] = level_losses[-1]
    stats[f'psnr_level{level}'] = reconstruction.true_psnr(rendering['rgb'], batch['rgb'], rays.lossmult)
  loss = level_losses[-1] + config.coarse_loss_mult * sum(level_losses[:-1])
  stats['weight_l2'] = reconstruction.weight_l2(params)
  loss += config.weight_decay_mult * stats['weight_l2']
  fine = history[-1]
  if config.occ_reg_loss_mult > 0:
    stats['loss_occ'] = occlusion.occlusion_loss(
        fine['density'], fine['rgb'], config.occ_reg_range, config.occ_wb_prior, config.occ_wb_range)
    loss += config.occ_reg_loss_mult * stats['loss_occ']
  if config.distortion_loss_mult > 0:
    s_vals = (fine['t_vals'] - rays.near) / (rays.far - rays.near)
    stats['loss_distortion'] = reconstruction.distortion_loss(s_vals, fine['weights'])
    loss += config.distortion_loss_mult * stats['loss_distortion']
  if random_poses.needs_patches(config):
    tvs = _depth_tvs(config, model, params, batch['patch_rays'], key, step, mask_point, mask_view)
    stats.update({f'depth_tv_level{level}': tv for level, tv in enumerate(tvs)})
    # As released: the coarse levels by coarse_loss_mult, the last by the scheduled weight.
    level_mults = [config.coarse_loss_mult] * (len(tvs) - 1) + [schedule.depth_tv_weight(config, step)]
    stats['loss_depth_tv'] = sum(mult * tv for mult, tv in zip(level_mults, tvs))
    loss += stats['loss_depth_tv']
  if prior_losses.any_on(config):  # Depth priors (#51): their own rays, rendered with the step's masks.
    prior_loss, prior_stats = prior_losses.loss_terms(config, model, params, batch, key, step,
                                                      (mask_point, mask_view))
    stats.update(prior_stats)
    loss += prior_loss
  if mask_point is not None:
    stats['mask_visible_point'] = jnp.mean(mask_point)
    stats['mask_visible_view'] = jnp.mean(mask_view)
  stats['loss'] = loss
  stats['psnr'] = stats[f'psnr_level{len(renderings) - 1}']
  return loss, stats


def _depth_tvs(config, model, params, patch_rays, key, step, mask_point, mask_view):
  """Unweighted depth TV per level [L] of the model on random-pose patch rays [P, ps, ps, ...]."""
  patch_shape = patch_rays.origins.shape[:3]
  rays = jax.tree.map(lambda x: x.reshape((-1, x.shape[-1])), patch_rays)
  if config.anneal_nearfar:
    rays = anneal.anneal_rays(config, rays, step)
  _, history = model.apply({'params': params}, random.fold_in(key, 1) if config.randomized else None, rays,
                           mask_point, mask_view, schedule.resample_padding(config, step))
  return jnp.stack([depth_smoothness.patch_depth_tv(level['weights'], level['t_vals'], patch_shape,
                                                    config.depth_tvnorm_mask_weight, config.regnerf_fix_released_bugs)
                    for level in history])


def _input_flags(batch) -> dict:
  """INPUT_CHECKS' flags of a batch: whether its Rays, and its other arrays, are finite."""
  rays = [value for key, value in batch.items() if key.endswith('rays')]
  return {'rays_finite': optim.all_finite(rays),
          'targets_finite': optim.all_finite([value for key, value in batch.items() if not key.endswith('rays')])}


def loss_terms(stats) -> list:
  """(stats key, weighting Config setting or '') of each loss term in stats, in the order compute_loss adds them."""
  terms = []
  for name, setting in LOSS_TERMS:
    if not name.endswith('level'):
      terms += [(name, setting)] if name in stats else []
      continue
    levels = sorted((k for k in stats if re.fullmatch(rf'{name}\d+', k)), key=lambda k: int(k[len(name):]))
    terms += [(k, 'coarse_loss_mult' if i < len(levels) - 1 else setting) for i, k in enumerate(levels)]
  return terms


def _weighted_term_flags(config, stats, step) -> dict:
  """'<term>_weighted_finite' of each weighted loss term of stats: whether it times its weight at step is finite."""
  weight = lambda setting: (schedule.depth_tv_weight(config, step) if setting == 'depth_tvnorm_loss_mult'
                            else getattr(config, setting))
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
