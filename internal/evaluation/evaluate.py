"""Evaluation of a run's newest checkpoint on its test views: the metrics.json record, a per-image CSV, images."""

import csv
import io
import os
import warnings

import jax
import numpy as np

from internal import atomic
from internal import configs
from internal.run import checkpoints
from internal import datasets
from internal.evaluation import camera_evaluation
from internal.evaluation import depth_metrics
from internal.datasets import loader
from internal.evaluation import inference
from internal.evaluation import lpips
from internal.evaluation import metrics
from internal.evaluation import results
from internal.run import run_dir as run_dir_lib
from internal.evaluation import vis


def output_dir(root: str, step: int) -> str:
  """<root>/test_preds_step_<step>; root is run_dir.outputs_root(config): Config.output_dir or the run directory."""
  return os.path.join(root, f'test_preds_step_{step}')


def existing_record(config):
  """The metrics.json record of the run's newest step if that step was evaluated, else None."""
  run_dir = run_dir_lib.check_run_dir(config)
  out_dir = output_dir(run_dir_lib.outputs_root(config), checkpoints.latest_step(run_dir))
  path = os.path.join(out_dir, results.METRICS_FILENAME)
  return results.read_record(path) if os.path.isfile(path) else None


def load_lpips_fn(config):
  """(lpips function or None, reason it is None): LPIPS-VGG unless Config.compute_lpips is False."""
  if not config.compute_lpips:
    return None, 'Config.compute_lpips = False'
  try:
    return lpips.load_lpips('vgg', config.lpips_weights_path, config.lpips_input_range), None
  except lpips.LpipsUnavailable as e:
    return None, str(e)


def check_eval_inputs(config) -> datasets.Dataset:
  """Before training: loads the test split (images, DTU masks) so that a missing file raises now, not after
  training, and returns it; warns when LPIPS will be reported as null."""
  test_set = datasets.load_dataset('test', config)
  if config.compute_lpips:
    _, reason = load_lpips_fn(config)
    if reason:
      warnings.warn(f'LPIPS will be null in metrics.json: {reason} (Config.compute_lpips = False silences this)',
                    stacklevel=2)
  return test_set


def select_positions(config, num_views: int) -> list:
  """Positions of the test views to evaluate: Config.eval_test_ids (checked) or all."""
  if config.eval_test_ids is None:
    return list(range(num_views))
  return checked_positions(config.eval_test_ids, num_views, 'eval_test_ids')


def checked_positions(ids, num_views: int, setting: str) -> list:
  """ids as a list of ints; ValueError naming Config.<setting> when one is outside 0..num_views - 1."""
  positions = [int(i) for i in ids]
  bad = [i for i in positions if not 0 <= i < num_views]
  if bad:
    raise ValueError(f'Config.{setting} = {list(ids)}: positions {bad} are outside the {num_views} test views '
                     f'(0..{num_views - 1})')
  return positions


def is_complete(config) -> bool:
  """True when every test view is evaluated at full resolution (a dropped missing view counts as incomplete)."""
  return config.eval_test_ids is None and config.eval_factor == 1 and not config.allow_missing_test_views


def save_images(rendering, out_dir: str, view_id: int) -> None:
  """Writes color_, depth_ and opacity_<view_id>.png of one rendered view, and its raw depth_<view_id>.npz."""
  for name, image in vis.visualize(rendering).items():
    vis.save_png(image, os.path.join(out_dir, f'{name}_{view_id:03d}.png'))
  np.savez_compressed(depth_metrics.depth_file(out_dir, view_id),
                      distance=np.asarray(rendering['distance_mean'], np.float32),
                      acc=np.asarray(rendering['acc'], np.float32))


def write_csv(per_image: list, path: str) -> None:
  """One row per evaluated view: id and every metric (empty when unavailable)."""
  text = io.StringIO()
  writer = csv.DictWriter(text, fieldnames=list(per_image[0]))
  writer.writeheader()
  writer.writerows({k: ('' if v is None else v) for k, v in row.items()} for row in per_image)
  atomic.write_text(path, text.getvalue())


def evaluate(config) -> dict:
  """Renders and scores the test views of the run's newest checkpoint; returns the metrics.json record."""
  run_dir = run_dir_lib.check_run_dir(config)
  test_set = datasets.load_dataset('test', config, ground_truth=True)  # Exact depths for the depth metrics.
  positions = select_positions(config, len(test_set.ids))
  # The training split as trained on, where the evaluation places the test cameras (None otherwise).
  train_set = datasets.load_dataset('train', config) if camera_evaluation.places_test_cameras(config) else None
  model, state = checkpoints.restore_model(config, run_dir, jax.tree.map(lambda x: x[0, 0, :8], test_set.rays),
                                           train_set)
  step = int(state.step)  # The newest intact checkpoint's.
  out_dir = output_dir(run_dir_lib.outputs_root(config), step)
  metrics_path = os.path.join(out_dir, results.METRICS_FILENAME)
  if os.path.exists(metrics_path) and not config.overwrite:
    raise FileExistsError(f'{metrics_path!r} exists (step {step} was evaluated already); set '
                          'Config.overwrite = True to evaluate again and replace it')
  run_dir_lib.make_output_folder(config, out_dir)
  render_fn = inference.make_render_fn(config, model, state.params, step)
  lpips_fn, lpips_reason = load_lpips_fn(config)
  dataset, scene = loader.filed_as(config)
  ndc = loader.REGISTRY[dataset].ndc(config)  # A run's rays are those of the dataset it is filed under.
  depth_scores = [depth_metrics.scorer(test_set, ndc)]  # Exact depths (generated scenes).
  if config.depth_reference_dir:
    depth_scores.append(depth_metrics.reference_scorer(test_set, ndc, config.depth_reference_dir, positions))
  if config.dataset_loader == 'capture':  # A capture's structure-from-motion points (#51).
    depth_scores.append(depth_metrics.sfm_scorer(test_set, ndc, config))
  test_rays, camera_record, scale = camera_evaluation.evaluation_rays(config, model, state, step, test_set, train_set)
  per_image = []
  for i in positions:
    rendering = inference.render_image(render_fn, jax.tree.map(lambda x, i=i: x[i], test_rays),
                                       config.render_chunk_size)
    if not ndc:  # Distances in the frame of the test cameras.
      rendering['distance_mean'] = rendering['distance_mean'] / scale
    mask = None if test_set.masks is None else test_set.masks[i]
    values = metrics.image_metrics(rendering['rgb'], test_set.images[i], lpips_fn, mask)
    for depth_score in filter(None, depth_scores):
      values.update(depth_score(i, rendering['distance_mean']))
    per_image.append({'id': int(test_set.ids[i]), **values})
    save_images(rendering, out_dir, int(test_set.ids[i]))
    print(f'view {test_set.ids[i]}: ' + ', '.join(f'{k} {v:.4f}' for k, v in values.items() if v is not None))
  record = results.make_record(dataset, scene, config.n_input_views, config.expname, step, per_image,
                              is_complete(config))
  record.update(lpips_missing_reason=lpips_reason, eval_factor=config.eval_factor,
                seeds=[getattr(config, name) for name in configs.declared(configs.SEED)],
                test_positions=positions, run_dir=os.path.abspath(run_dir))
  if camera_record is not None:
    record['means'].update(camera_evaluation.metrics(camera_record['errors'], camera_record.get('test_pose_moves')))
    record['cameras'] = camera_record
  write_csv(per_image, os.path.join(out_dir, 'metrics.csv'))
  results.write_record(metrics_path, record)
  return record
