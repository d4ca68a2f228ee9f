"""Camera refinement (Config.optimize_cameras): a learned rigid correction of every training camera, trained with
the model in the one jitted step, with its own learning rate, warm-up and decay (Adam with a large epsilon,
Config.camera_adam_eps: steps in proportion to small gradients).

A view's correction is an axis-angle rotation omega [3] about the camera's centre and a translation tau [3], both
in world axes, zero at the start (datasets/pose_correction.py: c2w = [R | C] -> [exp(omega) R | C + tau]). tau is
its free parameters in scene units, or with Config.camera_shift_in_distances in units of the camera distance
(camera_noise.camera_distance): a view's image then moves about as far for a step of its shift as of its turn, which
matters where steps follow the gradients' size (the large epsilon) and the scene's units are far from the distance.
The step builds the batch's rays from the corrected cameras (origins, directions, mip-NeRF's radii, NDC for LLFF-like
scenes), so the loss's gradient reaches the corrections.

The gauge: turning, moving or scaling every camera and the scene together changes no image, so the corrections
are kept where no such motion hides in them: the free parameters [N, 6] are projected to corrections whose rotation
vectors and translations have mean zero and whose translations have no mean component along the cameras' offsets
from their centroid (no global scaling). The mean rather than one fixed view, because every view is equally
uncertain (noise, few-photo structure-from-motion): fixing one would tie the frame to that view's error. The frame
can still drift by what the first-order projection leaves; evaluation aligns cameras by a similarity anyway.
"""

from typing import Any

import flax
import jax
import jax.numpy as jnp
import numpy as np

from internal.datasets import base, camera_noise, loader, pose_correction
from internal.training import optim, schedule


@flax.struct.dataclass
class CameraState:
  """The corrections' free parameters [N, 6] (omega, tau) and Adam moments; the given centres [N, 3] (constants);
  how the scene's rays follow from its cameras and the scene length of a unit of shift (static)."""
  free: jax.Array
  opt_state: Any
  centres: jax.Array
  space: pose_correction.RaySpace = flax.struct.field(pytree_node=False)
  shift_unit: float = flax.struct.field(pytree_node=False, default=1.)


def init(config, dataset: base.Dataset) -> CameraState:
  """Zero corrections of the training views of dataset (as loaded: noise included)."""
  free = jnp.zeros((len(dataset.ids), 6), jnp.float32)
  space = loader.ray_space(config, dataset)
  unit = camera_noise.camera_distance(dataset, space) if config.camera_shift_in_distances else 1.
  return CameraState(free=free, opt_state=optim.adam(config.camera_adam_eps).init(free),
                     centres=jnp.asarray(dataset.camtoworlds[:, :, 3], jnp.float32), space=space,
                     shift_unit=float(unit))


def gauge_fixed(free, centres, xp=jnp):
  """Corrections [N, 6] of free parameters [N, 6]: rotation vectors and translations of mean zero, translations
  without a component along the centres' offsets [N, 3] from their centroid (module docstring)."""
  omega = free[:, :3] - xp.mean(free[:, :3], axis=0)
  tau = free[:, 3:] - xp.mean(free[:, 3:], axis=0)
  offsets = centres - xp.mean(centres, axis=0)
  spread = xp.sum(offsets * offsets)
  scaling = xp.sum(tau * offsets) / xp.where(spread > 0, spread, 1.)
  return xp.concatenate([omega, tau - scaling * offsets], axis=1)


def view_corrections(free, centres, shift_unit: float = 1.) -> tuple:
  """(rotations [N, 3, 3], shifts [N, 3]) of the gauge-fixed corrections of free parameters [N, 6], the shifts
  in units of shift_unit."""
  corrections = gauge_fixed(free, centres)
  return pose_correction.so3_exp(corrections[:, :3], jnp), shift_unit * corrections[:, 3:]


def corrected_batch(cameras: CameraState, free, batch: dict) -> dict:
  """The batch with its rays made from the corrected cameras of its views (batch['view'] [B])."""
  rotations, shifts = view_corrections(free, cameras.centres, cameras.shift_unit)
  view = batch['view']
  rays = pose_correction.corrected_rays(batch['rays'], rotations[view], cameras.centres[view], shifts[view],
                                        cameras.space, batch.get('neighbour_dirs'), jnp)
  return {**batch, 'rays': rays}


def value_and_grads(loss_fn, params, cameras: CameraState, batch: dict, key, step):
  """((loss, stats), (model gradients, free-parameter gradients [N, 6])) of loss_fn(params, batch, key, step) on
  the batch's rays made from the corrected cameras."""
  def loss(params, free):
    return loss_fn(params, corrected_batch(cameras, free, batch), key, step)
  return jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)(params, cameras.free)


def learning_rate(config, step):
  """The corrections' learning rate at a (possibly traced) step."""
  return schedule.learning_rate(step, config.camera_lr_init, config.camera_lr_final, config.max_steps,
                                config.camera_lr_delay_steps, config.camera_lr_delay_mult)


def update(config, cameras: CameraState, grads, step) -> tuple:
  """(CameraState after one Adam step on the gradients [N, 6], stats: its learning rate and mean rotation)."""
  lr = learning_rate(config, step)
  updates, opt_state = optim.adam(config.camera_adam_eps).update(grads, cameras.opt_state, cameras.free)
  cameras = cameras.replace(free=cameras.free - lr * updates, opt_state=opt_state)
  angles = jnp.linalg.norm(gauge_fixed(cameras.free, cameras.centres)[:, :3], axis=1)
  return cameras, {'camera_lr': lr, 'camera_correction_deg': jnp.rad2deg(jnp.mean(angles))}


def refined_cameras(cameras: CameraState, given: np.ndarray) -> np.ndarray:
  """[N, 3, 4] the given training cameras [N, 3, 4] corrected by the state's corrections (float64)."""
  free, centres = (np.asarray(jax.device_get(x), np.float64) for x in (cameras.free, cameras.centres))
  corrections = gauge_fixed(free, centres, np)
  return pose_correction.corrected_cameras(given, pose_correction.so3_exp(corrections[:, :3]),
                                           cameras.shift_unit * corrections[:, 3:])
