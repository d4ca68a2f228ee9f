"""Learning curves: the test PSNR of a few test views at reduced size every Config.curve_every steps of training.

The paper's story is dynamic (the baseline overfits early, FreeNeRF does not): a curve shows it. A row is
{'step', 'psnr', 'psnr_masked' (DTU only), 'seconds', 'compile_seconds'}: the mean over the curve's views of their
PSNR computed as evaluation computes it (and the DTU protocol's object-masked PSNR), the wall-clock seconds of
training so far, the curve's own evaluations left out, and how many of those seconds compiled the step (the first
step of each call of training: seconds - compile_seconds are the seconds of steps); where the training cameras may
move (camera_evaluation.py) also the camera errors at that step, the views then carried into the training frame as
evaluation carries them. Rows go to tensorboard (curve/psnr, curve/psnr_masked, curve/eval_seconds) and to
<run dir>/learning_curve.csv, rewritten atomically at every row. Every checkpoint also writes the clock
(learning_curve_clock.json: the step and both seconds), so a resumed run's seconds go on from its checkpoint's step:
a run trained in several calls (GPU windows) reads as one run. A resumed run keeps the rows up to its checkpoint's
step; without a clock of that step its seconds go on from the last kept row (training time after that row, lost
with the interrupted steps, is not counted).
"""

import csv
import dataclasses
import io
import json
import os
import time
from typing import List, NamedTuple, Optional

import jax
import numpy as np

from internal import atomic
from internal import datasets
from internal import rays as rays_lib
from internal.datasets import base
from internal.evaluation import camera_evaluation
from internal.evaluation import evaluate
from internal.evaluation import inference
from internal.evaluation import metrics
from internal.evaluation import results
from internal.run import sharding

CSV_FILE = 'learning_curve.csv'
CLOCK_FILE = 'learning_curve_clock.json'


class Views(NamedTuple):
  """The curve's test views: images f32 [V,h,w,3], DTU masks [V,h,w,3] or None, rays [V,h,w,...], view ids."""
  images: np.ndarray
  masks: Optional[np.ndarray]
  rays: rays_lib.Rays
  ids: List[int]


def load_views(config, test_set: datasets.Dataset) -> Optional[Views]:
  """The test views at curve_positions, at Config.factor * Config.curve_factor; None when off.

  test_set is the test split loaded at Config.eval_factor, reused when the factors agree.
  """
  if not config.curve_every:
    return None
  if config.curve_factor != config.eval_factor:
    test_set = datasets.load_dataset('test', dataclasses.replace(config, eval_factor=config.curve_factor))
  positions = curve_positions(config, len(test_set.ids))
  masks = None if test_set.masks is None else test_set.masks[positions]
  return Views(test_set.images[positions], masks, rays_lib.map_rays(lambda x: x[positions], test_set.rays),
               [int(test_set.ids[p]) for p in positions])


def curve_positions(config, num_views: int) -> list:
  """Test-split positions of the curve's views: Config.curve_spread_views evenly spread over num_views, the
  middle view of each equal part, floor((i + 1/2) * num_views / k); else Config.curve_test_ids (checked)."""
  k = config.curve_spread_views
  if not k:
    return evaluate.checked_positions(config.curve_test_ids, num_views, 'curve_test_ids')
  if k > num_views:
    raise ValueError(f'Config.curve_spread_views = {k}: the test split has only {num_views} views')
  return [(2 * i + 1) * num_views // (2 * k) for i in range(k)]


def curve_row(step: int, seconds: float, images, renders, masks=None, compile_seconds=None) -> dict:
  """{'step', 'psnr'[, 'psnr_masked'], 'seconds'[, 'compile_seconds']} of renders [V][h,w,3] against images
  [V][h,w,3].

  PSNRs are averaged over the views as evaluation's means are; psnr_masked (with DTU masks [V][h,w,3]) only
  counts the values whose mask is 1, as the DTU protocol does.
  """
  row = {'step': int(step), 'psnr': results.mean([metrics.psnr(r, g) for r, g in zip(renders, images)])}
  if masks is not None:
    row['psnr_masked'] = results.mean([metrics.masked_psnr(r, g, m) for r, g, m in zip(renders, images, masks)])
  row['seconds'] = float(seconds)
  if compile_seconds is not None:
    row['compile_seconds'] = float(compile_seconds)
  return row


def csv_path(run_dir: str) -> str:
  """<run_dir>/learning_curve.csv."""
  return os.path.join(run_dir, CSV_FILE)


def read_clock(run_dir: str, step: int):
  """(seconds, compile_seconds) of training up to step, as the checkpoint of step recorded them; None when the
  clock is of another step (a checkpoint saved after it, or none recorded) or unreadable."""
  try:
    with open(os.path.join(run_dir, CLOCK_FILE)) as f:
      clock = json.load(f)
    return (float(clock['seconds']), float(clock['compile_seconds'])) if clock['step'] == step else None
  except (OSError, ValueError, KeyError, TypeError):
    return None


def read_rows(path: str) -> List[dict]:
  """The rows of a learning_curve.csv (step an int, other columns floats or None when empty); [] when absent."""
  if not os.path.isfile(path):
    return []
  with open(path, newline='') as f:
    try:
      return [{'step': int(row['step']), **{k: None if v == '' else float(v) for k, v in row.items() if k != 'step'}}
              for row in csv.DictReader(f)]
    except (KeyError, TypeError, ValueError) as err:
      raise ValueError(f'{path!r} is not a learning curve ({type(err).__name__}: {err}); expected the columns '
                       'step, psnr[, psnr_masked], seconds with numbers') from err


class CurveLog:
  """A run's learning_curve.csv: the rows up to the resumed step, then each new row; rewritten atomically."""

  def __init__(self, run_dir: str, resumed_step: int):
    self.path = csv_path(run_dir)
    rows = read_rows(self.path)
    self.rows = [row for row in rows if row['step'] <= resumed_step]
    if len(self.rows) < len(rows):  # Rows of steps the resumed run trains again.
      self._write()

  def append(self, row: dict) -> None:
    """Adds a row whose step follows every kept one and rewrites the file."""
    if self.rows and row['step'] <= self.rows[-1]['step']:
      raise ValueError(f'{self.path!r}: step {row["step"]} does not follow step {self.rows[-1]["step"]}')
    self.rows.append(row)
    self._write()

  def _write(self) -> None:
    """Writes every row (empty cells for missing values) through a temporary file."""
    fields = list(dict.fromkeys(k for row in self.rows for k in row)) or ['step', 'psnr', 'seconds']
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=fields, restval='')
    writer.writeheader()
    writer.writerows({k: '' if v is None else v for k, v in row.items()} for row in self.rows)
    atomic.write_text(self.path, text.getvalue())


class Recorder:
  """Scores the curve's views every Config.curve_every steps and at the last step; tensorboard and the CSV."""

  def __init__(self, config, model, views: Views, run_dir: str, writer, resumed_step: int, cameras=None):
    """cameras: where the training cameras may move (CurveCameras), what carries the views into
    the training frame at each point and gives the camera errors of the row."""
    self.config, self.model, self.views, self.writer, self.run_dir = config, model, views, writer, run_dir
    self.cameras = cameras
    self.log = CurveLog(run_dir, resumed_step)
    self.compiled = inference.compile_render(config, model)  # One compilation for every curve point.
    last = self.log.rows[-1] if self.log.rows else {}
    self.seconds_before, self.compile_seconds = read_clock(run_dir, resumed_step) or (
        last.get('seconds', 0.), last.get('compile_seconds') or 0.)
    self.start, self.eval_seconds = time.perf_counter(), 0.

  def due(self, step: int) -> bool:
    """Whether step gets a curve point."""
    return step % self.config.curve_every == 0 or step == self.config.max_steps

  def seconds(self) -> float:
    """Seconds of training so far (the runs before this call's included), the curve's evaluations left out."""
    return self.seconds_before + time.perf_counter() - self.start - self.eval_seconds

  def compiled_step(self, seconds: float) -> None:
    """Counts seconds spent compiling the step (the first step of a call of training)."""
    self.compile_seconds += seconds

  def checkpointed(self, step: int) -> None:
    """Records the clock of a checkpoint just saved at step (the steps before it done), for a resumed run."""
    atomic.write_text(os.path.join(self.run_dir, CLOCK_FILE), json.dumps(
        {'step': int(step), 'seconds': self.seconds(), 'compile_seconds': self.compile_seconds}))

  def record(self, step: int, params, camera_state=None) -> dict:
    """Renders and scores the views with the parameters of step (and the camera corrections camera_state, if
    refined); logs and appends the row; returns it."""
    params = jax.block_until_ready(sharding.local_copy(params))  # The steps dispatched so far count as training.
    tic = time.perf_counter()
    seconds = self.seconds()
    rays, camera_values = self.views.rays, {}
    if self.cameras is not None:
      rays, camera_values = self.cameras.at(None if camera_state is None else sharding.local_copy(camera_state))
    render_fn = inference.make_render_fn(self.config, self.model, params, step, compiled=self.compiled)
    renders = [inference.render_image(render_fn, rays_lib.map_rays(lambda x, i=i: x[i], rays),
                                      self.config.render_chunk_size)['rgb'] for i in range(len(self.views.ids))]
    row = {**curve_row(step, seconds, self.views.images, renders, self.views.masks, self.compile_seconds),
           **camera_values}
    self.log.append(row)
    elapsed = time.perf_counter() - tic
    self.eval_seconds += elapsed
    for name in ('psnr', 'psnr_masked', *camera_values):
      if name in row:
        self.writer.add_scalar(f'curve/{name}', row[name], step)
    self.writer.add_scalar('curve/eval_seconds', elapsed, step)
    return row


class CurveCameras:
  """The curve's views carried into the training frame at each curve point, with the camera errors of that step
  (camera_evaluation.py; Recorder's cameras)."""

  def __init__(self, config, train_set: datasets.Dataset):
    self.train_set = train_set
    self.reference = camera_evaluation.reference_cameras(config, train_set)
    test_set = datasets.load_dataset('test', dataclasses.replace(config, eval_factor=config.curve_factor))
    self.views = base.subset(test_set, curve_positions(config, len(test_set.ids)))

  def at(self, camera_state) -> tuple:
    """(the views' rays [V,h,w,...] in the frame of the training cameras of camera_state (None: as given), the
    camera metrics of metrics.json at this step)."""
    cameras = camera_evaluation.training_cameras(self.train_set, camera_state, self.reference)
    rotations, shifts = camera_evaluation.aligned_corrections(self.views, camera_evaluation.test_similarity(cameras))
    return (camera_evaluation.test_rays(self.views, self.train_set, rotations, shifts),
            camera_evaluation.metrics(camera_evaluation.errors(cameras)))
