"""Honest evaluation of runs whose training cameras differ from the test cameras' frame (refinement, noise, a
capture's separate training model): test cameras brought into the training frame, camera errors.

The test cameras live in the frame of the reference training cameras: the loader's, before any study noise
(Config.camera_noise_*) and from Config.capture_model rather than capture_train_model. The similarity that best maps
those reference cameras onto the final training cameras (refined, or as given when not refined;
cameras/alignment.py, as BARF evaluates) carries the test cameras into the frame the model was trained in;
optionally each test camera is then refined on its own image with the model frozen (Config.test_pose_steps,
BARF's test-time pose optimization). Camera errors are after a similarity too: the final cameras against the
given ones (what refinement moved) and against the reference (the true cameras where the loader's are exact: the
generated scene, Blender, DTU's calibration). A similarity explains part of any error (cameras/alignment.py), so
where the training cameras start in the reference's frame (noise and refinement move them from it; a capture's
separate training model has a frame of its own) the errors against the reference are reported without it too
(*_unaligned): on the generated scene, whose frame is known, those read the noise whole.
"""

import dataclasses
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from internal import datasets
from internal.cameras import alignment, corrections
from internal.datasets import batching, camera_noise, loader
from internal.evaluation import pose_progress
from internal.models import freq_schedule
from internal.training import camera_refinement, optim

# Datasets (loader.filed_as) whose cameras are exact or calibrated, the reference then being the truth; and the
# generated scene's loader.
EXACT_DATASETS = ('blender', 'dtu')


def needs_alignment(config) -> bool:
  """Whether the training cameras may differ from the test cameras' frame."""
  return bool(config.optimize_cameras or camera_noise.is_on(config) or config.capture_train_model)


def places_test_cameras(config) -> bool:
  """Whether the evaluation places the test cameras itself: by the similarity where the training cameras may move,
  then by test-time pose optimization where Config.test_pose_steps asks for it (exact cameras included, so that
  runs on exact and on moved cameras can be evaluated under one protocol)."""
  return needs_alignment(config) or config.test_pose_steps > 0


def reference_config(config):
  """Config whose training split holds the reference cameras: no noise, Config.capture_model's cameras."""
  return dataclasses.replace(config, camera_noise_rotation_deg=0., camera_noise_translation=0., capture_train_model='')


class TrainingCameras(NamedTuple):
  """The training cameras [N,3,4] as given, as finally trained on, and in the test cameras' frame; the camera
  distance of the reference (the unit of translation errors); whether the given cameras are in the reference's
  frame."""
  given: np.ndarray
  final: np.ndarray
  reference: np.ndarray
  distance: float
  shared_frame: bool


# What the camera metrics of metrics.json measure (its 'cameras' record says it beside them).
METRIC_WORDS = {
    'camera_rotation_deg': 'median rotation error (degrees) of the final training cameras against the reference, '
                           'after the similarity taking them onto it',
    'camera_translation': 'median centre distance (of the camera distance) of the final training cameras from the '
                          'reference, after the similarity taking them onto it',
    'camera_rotation_deg_unaligned': 'camera_rotation_deg without the similarity (the cameras share its frame)',
    'camera_translation_unaligned': 'camera_translation without the similarity (the cameras share its frame)',
    'test_pose_rotation_deg': 'median angle (degrees) by which test-time pose optimization turned the test cameras '
                              'from where the similarity placed them',
    'test_pose_translation': 'median distance (of the camera distance) by which test-time pose optimization moved '
                             'the test cameras\' centres from where the similarity placed them'}


def reference_cameras(config, train_set: datasets.Dataset) -> tuple:
  """(reference training cameras [N,3,4], their camera distance, whether the given cameras share their frame) of
  the training views of train_set."""
  reference = datasets.load_dataset('train', reference_config(config))
  distance = alignment.camera_distance(reference.camtoworlds, reference.space)
  return np.asarray(reference.camtoworlds, np.float64), distance, not config.capture_train_model


def training_cameras(train_set: datasets.Dataset, camera_state, reference: tuple) -> TrainingCameras:
  """The TrainingCameras of a run: camera_state its CameraState (None: not refined), reference of
  reference_cameras."""
  given = np.asarray(train_set.camtoworlds, np.float64)
  final = given if camera_state is None else camera_refinement.refined_cameras(camera_state, given)
  return TrainingCameras(given, final, *reference)


def errors(cameras: TrainingCameras) -> dict:
  """Camera errors (alignment.errors) of the final cameras against the given ones and the reference, and of the
  given ones against the reference, after the similarity; against the reference also without it ('_unaligned')
  where the frames are shared; medians, means, maxima and per view."""
  pairs = {'final_vs_given': (cameras.final, cameras.given, True),
           'final_vs_reference': (cameras.final, cameras.reference, True),
           'given_vs_reference': (cameras.given, cameras.reference, True)}
  if cameras.shared_frame:
    pairs.update(final_vs_reference_unaligned=(cameras.final, cameras.reference, False),
                 given_vs_reference_unaligned=(cameras.given, cameras.reference, False))
  out = {}
  for name, (a, b, align) in pairs.items():
    values = alignment.errors(a, b, cameras.distance, align)
    out[name] = {**alignment.summary(values), 'per_view': {k: v.tolist() for k, v in values.items()}}
  return out


def test_pose_moves(before: tuple, after: tuple, distance: float) -> dict:
  """How far test-time pose optimization moved each test camera from the (rotations [M,3,3], shifts [M,3]) of
  before to those of after: the angle (degrees) between the rotations and the distance of the centres, a fraction
  of distance; medians too."""
  turns = np.degrees(alignment.rotation_angle(after[0] @ np.swapaxes(before[0], -1, -2)))
  moves = np.linalg.norm(np.asarray(after[1], np.float64) - before[1], axis=-1) / distance
  return {'rotation_deg_median': float(np.median(turns)), 'translation_median': float(np.median(moves)),
          'per_view': {'rotation_deg': turns.tolist(), 'translation': moves.tolist()}}


def metrics(error_record: dict, moves: Optional[dict] = None) -> dict:
  """The camera metrics of metrics.json's means (METRIC_WORDS): median errors of the final cameras against the
  reference, after the similarity and, where the frames are shared, without it; how far test-time pose
  optimization moved the test cameras (moves of test_pose_moves), where it ran."""
  out = {}
  if moves is not None:
    out.update(test_pose_rotation_deg=moves['rotation_deg_median'], test_pose_translation=moves['translation_median'])
  for suffix in ('', '_unaligned'):
    against = error_record.get('final_vs_reference' + suffix)
    if against is not None:
      out.update({f'camera_rotation_deg{suffix}': against['rotation_deg_median'],
                  f'camera_translation{suffix}': against['translation_median']})
  return out


def test_similarity(cameras: TrainingCameras) -> alignment.Similarity:
  """The similarity carrying the test cameras' frame into the final training cameras' frame."""
  return alignment.fit(cameras.reference, cameras.final)


def aligned_corrections(test_set: datasets.Dataset, similarity: alignment.Similarity) -> tuple:
  """(rotations [M,3,3], shifts [M,3]) that carry the test cameras of test_set by the similarity."""
  c2w = np.asarray(test_set.camtoworlds, np.float64)
  moved = similarity.cameras(c2w)
  return np.repeat(similarity.rotation[None], len(c2w), 0), moved[:, :, 3] - c2w[:, :, 3]


def test_rays(test_set: datasets.Dataset, train_set: datasets.Dataset, rotations, shifts):
  """Rays [M,H,W,...] of the test cameras corrected by rotations [M,3,3] and shifts [M,3], with the training
  rays' near and far (the range the model was trained on)."""
  rays = corrections.corrected_image_rays(test_set.rays, test_set.cameras, rotations, shifts, test_set.space)
  return rays._replace(near=np.full_like(rays.near, train_set.near), far=np.full_like(rays.far, train_set.far))


def _view_batch(config, test_set: datasets.Dataset, flat, v: int, k: int) -> tuple:
  """(rays [B,...], colours [B,3], their Pixels) of Config.batch_size pixels of test view v for its k-th step, drawn
  from np.random.default_rng([Config.np_rng_seed, view id, k]); flat: its rays [M,H*W,...]."""
  size = test_set.height * test_set.width
  pixel = np.random.default_rng([config.np_rng_seed, int(test_set.ids[v]), k]).integers(size, size=config.batch_size)
  colours = test_set.images[v].reshape(-1, 3)[pixel]
  pixels = batching.pixels_of((np.full(len(pixel), v), pixel), test_set.width)
  return type(flat)(*[x[v, pixel] for x in flat]), colours, pixels


def test_time_poses(config, model, params, step: int, test_set: datasets.Dataset, rotations, shifts,
                    on_step=None) -> tuple:
  """(rotations [M,3,3], shifts [M,3]) refined per test view on its own image, the model frozen (as at step):
  Config.test_pose_steps Adam steps (Config.test_pose_lr) of the fine level's squared colour error (_view_batch).
  on_step(view, correction [6]), when given, follows every step (pose_progress.PoseProgress)."""
  space, cameras = test_set.space, test_set.cameras
  masks = freq_schedule.model_masks(config, model, jnp.asarray(step))
  adam = optim.adam(config.adam_eps)
  flat = type(test_set.rays)(*[x.reshape(len(test_set.ids), test_set.height * test_set.width, -1)
                               for x in test_set.rays])
  centres = np.asarray(test_set.camtoworlds, np.float32)[:, :, 3]

  def loss(delta, rays, rgb, pixels, rotation, centre, shift):
    turned = corrections.so3_exp(delta[:3], jnp) @ rotation
    moved = corrections.corrected_rays(rays, turned, centre, shift + delta[3:], space, jnp, cameras, pixels)
    renderings, _ = model.apply({'params': params}, None, moved, *masks, config.resample_padding_final)
    return jnp.mean((renderings[-1]['rgb'] - rgb)**2)

  @jax.jit
  def adam_step(delta, opt_state, *args):
    updates, opt_state = adam.update(jax.grad(loss)(delta, *args), opt_state, delta)
    return delta - config.test_pose_lr * updates, opt_state

  out_rotations, out_shifts = [], []
  for v in range(len(test_set.ids)):
    delta = jnp.zeros(6, jnp.float32)
    opt_state = adam.init(delta)
    camera = (jnp.asarray(rotations[v], jnp.float32), centres[v], jnp.asarray(shifts[v], jnp.float32))
    for k in range(config.test_pose_steps):
      delta, opt_state = adam_step(delta, opt_state, *_view_batch(config, test_set, flat, v, k), *camera)
      if on_step is not None:
        on_step(v, delta)
    delta = np.asarray(delta, np.float64)
    out_rotations.append(corrections.so3_exp(delta[:3]) @ rotations[v])
    out_shifts.append(shifts[v] + delta[3:])
  return np.stack(out_rotations), np.stack(out_shifts)


def reference_words(config) -> str:
  """What the reference cameras are, in words, for metrics.json."""
  if config.capture_train_model:
    return f'the cameras of Config.capture_model = {config.capture_model!r} (every photo\'s model)'
  filed, _ = loader.filed_as(config)
  exact = config.dataset_loader == 'generated' or filed in EXACT_DATASETS
  return 'the loader\'s cameras, ' + ('exact or calibrated' if exact else 'as given (not known to be exact)')


def evaluation_rays(config, model, state, step: int, test_set: datasets.Dataset,
                    train_set: Optional[datasets.Dataset]) -> tuple:
  """(test rays [M,H,W,...] in the frame the model was trained in, the 'cameras' record of metrics.json or None,
  the similarity's scale: rendered world distances over test-frame ones); train_set: the training split as trained
  on, None when needs_alignment is False (the test rays are then the loaded ones)."""
  if train_set is None:
    return test_set.rays, None, 1.
  cameras = training_cameras(train_set, getattr(state, 'cameras', None), reference_cameras(config, train_set))
  similarity = test_similarity(cameras)
  rotations, shifts = aligned_corrections(test_set, similarity)
  moves = None
  if config.test_pose_steps:
    with pose_progress.PoseProgress(config, len(test_set.ids)) as on_step:
      placed = test_time_poses(config, model, state.params, step, test_set, rotations, shifts, on_step)
    moves = test_pose_moves((rotations, shifts), placed, cameras.distance)
    rotations, shifts = placed
  record = {'refined': bool(config.optimize_cameras), 'reference': reference_words(config),
            'test_cameras': 'similarity' + (' + test-time pose optimization' if config.test_pose_steps else ''),
            'test_pose_steps': config.test_pose_steps,
            'similarity': {'scale': similarity.scale, 'rotation': similarity.rotation.tolist(),
                           'shift': similarity.shift.tolist()},
            'errors': errors(cameras)}
  if moves is not None:
    record['test_pose_moves'] = moves
  record['metrics'] = {name: METRIC_WORDS[name] for name in metrics(record['errors'], moves)}
  return test_rays(test_set, train_set, rotations, shifts), record, similarity.scale
