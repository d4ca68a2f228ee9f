"""Camera refinement (Config.optimize_cameras): a learned rigid correction of every training camera, trained with
the model in the one jitted step, with its own learning rate, warm-up and decay (Adam with a large epsilon,
Config.camera_adam_eps: steps in proportion to small gradients).

A view's correction is an axis-angle rotation omega [3] about the camera's centre and a translation tau [3], both
in world axes, zero at the start (cameras/corrections.py: c2w = [R | C] -> [exp(omega) R | C + tau]). tau is its
free parameters in scene units, or with Config.camera_shift_in_distances in units of the camera distance
(cameras/alignment.camera_distance): a view's image then moves about as far for a step of its shift as of its turn,
which matters where steps follow the gradients' size (the large epsilon) and the scene's units are far from the
distance. The step makes every ray family of the batch that comes from training views (the training pixels, the
depth priors' patches and points) again from the corrected cameras, once, before the loss terms (origins,
directions, mip-NeRF's radii, NDC for LLFF-like scenes: their radii from the neighbouring pixels' directions, cast
from the given cameras, which the state holds as constants of the step), so every term's gradient reaches the
corrections. RegNeRF's random-pose patches come from no training camera: they keep the frame the gauge holds.

The gauge: turning, moving or scaling every camera and the scene together changes no image, so the corrections
are kept where no such motion hides in them: the free parameters [N, 6] are projected to corrections whose rotation
vectors and translations have mean zero and whose translations have no mean component along the cameras' offsets
from their centroid (no global scaling). The mean rather than one fixed view, because every view is equally
uncertain (noise, few-photo structure-from-motion): fixing one would tie the frame to that view's error. The frame
can still drift by what the first-order projection leaves; evaluation aligns cameras by a similarity anyway.

Near the gauge: cameras around an object that all tilt by the same angle about their own x or y axis (up-down,
left-right) show the scene as if it had moved, save for parallax, so the photometric loss hardly sees such a shared
tilt (on the generated object rig exact cameras drifted into one, and noisy ones kept one the noise had brought:
results/studies/cameras_target_reach). With Config.camera_fix_shared_tilt the rotation vectors are projected onto
the complement of both the turns shared in world axes and those shared in the cameras' own x and y axes; measured
there, the drift stayed and noisy cameras were corrected worse, so it is off by default.
"""

from typing import Any

import flax
import jax
import jax.numpy as jnp
import numpy as np

from internal.cameras import alignment, corrections
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, batching
from internal.training import optim, schedule


class StaticCameras:
  """Cameras of numpy arrays as a static (hashable) part of a pytree: constants of the jitted step, equal when their
  values are."""

  def __init__(self, cameras: Cameras):
    self.cameras = cameras
    self._key = tuple(None if x is None else (x.dtype.str, x.shape, x.tobytes()) for x in cameras)

  def __eq__(self, other) -> bool:
    return isinstance(other, StaticCameras) and self._key == other._key

  def __hash__(self) -> int:
    return hash(self._key)


@flax.struct.dataclass
class CameraState:
  """The corrections' free parameters [N, 6] (omega, tau) and Adam moments; the given centres [N, 3] (constants);
  static: how the scene's rays follow from its cameras, the given cameras themselves and the scene length of a unit
  of shift."""
  free: jax.Array
  opt_state: Any
  centres: jax.Array
  space: RaySpace = flax.struct.field(pytree_node=False)
  given: StaticCameras = flax.struct.field(pytree_node=False)
  shift_unit: float = flax.struct.field(pytree_node=False, default=1.)
  tilt_axes: Any = None  # [N, 3, 2] the given cameras' own x and y axes with Config.camera_fix_shared_tilt, else None.


def init(config, dataset: base.Dataset) -> CameraState:
  """Zero corrections of the training views of dataset (as loaded: noise included)."""
  free = jnp.zeros((len(dataset.ids), 6), jnp.float32)
  given = Cameras(*(None if x is None else np.asarray(x, np.float32) for x in dataset.cameras))
  unit = alignment.camera_distance(dataset.camtoworlds, dataset.space) if config.camera_shift_in_distances else 1.
  tilt_axes = (jnp.asarray(dataset.camtoworlds[:, :, :2], jnp.float32) if config.camera_fix_shared_tilt
               else None)
  return CameraState(free=free, opt_state=optim.adam(config.camera_adam_eps).init(free),
                     centres=jnp.asarray(dataset.camtoworlds[:, :, 3], jnp.float32), space=dataset.space,
                     tilt_axes=tilt_axes, given=StaticCameras(given), shift_unit=float(unit))


def shared_turns_removed(omega, tilt_axes, xp=jnp):
  """Rotation vectors [N, 3] less their least-squares part of the turns all views share in world axes and the tilts
  they share about their own x and y axes (tilt_axes [N, 3, 2]; module docstring)."""
  n = omega.shape[0]
  basis = xp.concatenate([xp.tile(xp.eye(3), (n, 1)), tilt_axes.reshape(3 * n, 2)], axis=1)  # [3N, 5]
  flat = omega.reshape(3 * n)
  return (flat - basis @ (xp.linalg.pinv(basis) @ flat)).reshape(n, 3)


def gauge_fixed(free, centres, xp=jnp, tilt_axes=None):
  """Corrections [N, 6] of free parameters [N, 6]: rotation vectors and translations of mean zero (the rotation
  vectors also without a shared tilt where tilt_axes [N, 3, 2] are given), translations without a component along
  the centres' offsets [N, 3] from their centroid (module docstring)."""
  omega = free[:, :3] - xp.mean(free[:, :3], axis=0)
  if tilt_axes is not None:
    omega = shared_turns_removed(omega, tilt_axes, xp)
  tau = free[:, 3:] - xp.mean(free[:, 3:], axis=0)
  offsets = centres - xp.mean(centres, axis=0)
  spread = xp.sum(offsets * offsets)
  scaling = xp.sum(tau * offsets) / xp.where(spread > 0, spread, 1.)
  return xp.concatenate([omega, tau - scaling * offsets], axis=1)


def view_corrections(free, centres, shift_unit: float = 1., tilt_axes=None) -> tuple:
  """(rotations [N, 3, 3], shifts [N, 3]) of the gauge-fixed corrections of free parameters [N, 6], the shifts
  in units of shift_unit."""
  fixed = gauge_fixed(free, centres, jnp, tilt_axes)
  return corrections.so3_exp(fixed[:, :3], jnp), shift_unit * fixed[:, 3:]


def corrected_batch(cameras: CameraState, free, batch: batching.Batch) -> batching.Batch:
  """The batch with the rays of every family of training views (their Pixels) made from the corrected cameras."""
  rotations, shifts = view_corrections(free, cameras.centres, cameras.shift_unit, cameras.tilt_axes)
  fields = {}
  for rays_field, pixels_field in batching.FAMILIES:
    pixels = getattr(batch, pixels_field) if pixels_field else None
    if pixels is not None:
      view = pixels.view
      fields[rays_field] = corrections.corrected_rays(getattr(batch, rays_field), rotations[view],
                                                      cameras.centres[view], shifts[view], cameras.space, jnp,
                                                      cameras.given.cameras, pixels)
  return batch._replace(**fields)


def value_and_grads(loss_fn, params, cameras: CameraState, batch: batching.Batch, key, step):
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
  angles = jnp.linalg.norm(gauge_fixed(cameras.free, cameras.centres, jnp, cameras.tilt_axes)[:, :3], axis=1)
  return cameras, {'camera_lr': lr, 'camera_correction_deg': jnp.rad2deg(jnp.mean(angles))}


def refined_cameras(cameras: CameraState, given: np.ndarray) -> np.ndarray:
  """[N, 3, 4] the given training cameras [N, 3, 4] corrected by the state's corrections (float64)."""
  free, centres = (np.asarray(jax.device_get(x), np.float64) for x in (cameras.free, cameras.centres))
  tilt_axes = None if cameras.tilt_axes is None else np.asarray(jax.device_get(cameras.tilt_axes), np.float64)
  fixed = gauge_fixed(free, centres, np, tilt_axes)
  return corrections.corrected_cameras(given, corrections.so3_exp(fixed[:, :3]), cameras.shift_unit * fixed[:, 3:])
