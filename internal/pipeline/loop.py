"""The training loop: resumable training of one run with checkpoints, progress, previews and signal handling."""

import contextlib
import dataclasses
import os
import signal
import time
from typing import Optional

import jax
import numpy as np
from jax import random
import tqdm

from internal.run import camera_export
from internal.run import checkpoints
from internal.run import disk_full
from internal.run import event_file
from internal import datasets
from internal.run import distributed
from internal.evaluation import camera_evaluation
from internal.evaluation import evaluate
from internal.evaluation import inference
from internal.evaluation import learning_curve
from internal.evaluation import metrics
from internal.run import run_dir as run_dir_lib
from internal.run import out_of_memory
from internal.run import sharding
from internal.run import stuck
from internal.training import train_step as train_step_lib
from internal.evaluation import vis
from internal import progress
from internal.datasets import depth_prior, random_poses
from internal.training import camera_refinement

PREVIEW_INDEX = 0  # The test view rendered every Config.train_render_every steps.


@dataclasses.dataclass
class TrainResult:
  """What a call of `train` ends with; signum is the signal that stopped it early (else None)."""
  model: object
  state: train_step_lib.TrainState
  run_dir: str
  signum: object = None
  skipped: int = 0  # Updates skipped for non-finite values in this call.


class StopFlag:
  """A signal handler that only records the signal: the loop saves a checkpoint and stops at the next step."""

  def __init__(self):
    self.signum = None

  def __call__(self, signum, frame):
    self.signum = self.signum or signum  # The first signal is the one that stopped training.

  def raise_unless_stopped(self, signum, frame):
    """A handler for around training: KeyboardInterrupt (stop at once) until a signal stopped training, then
    nothing, as the process is stopping already (e.g. a second request while it releases what it holds)."""
    del signum, frame
    if self.signum is None:
      raise KeyboardInterrupt

  def stopping(self, sync_point: bool) -> bool:
    """True when the loop must stop after this step.

    With several processes they must stop at the same step: they agree at sync points only, where a signal
    that any of them got stops them all.
    """
    if jax.process_count() > 1:
      if not sync_point:
        return False
      self.signum = distributed.max_over_processes(self.signum or 0) or None
    return self.signum is not None


class NullWriter:
  """The tensorboard writer of processes other than process 0: logs nothing."""

  def add_scalar(self, *args, **kwargs):
    """Logs nothing."""

  add_image = add_scalar

  def __enter__(self):
    return self

  def __exit__(self, *exc):
    return False


@contextlib.contextmanager
def stop_on_signals(flag: Optional[StopFlag] = None):
  """Installs flag (default: a new StopFlag) for SIGINT and SIGTERM for the duration of the block; yields it."""
  flag = StopFlag() if flag is None else flag
  previous = {s: signal.signal(s, flag) for s in (signal.SIGINT, signal.SIGTERM)}
  try:
    yield flag
  finally:
    for s, handler in previous.items():
      signal.signal(s, handler)


class StepReport:
  """Per-step stats kept on device and fetched every Config.print_every steps: tqdm bar and tensorboard.

  The bar counts steps whose stats were fetched (so finished), not steps dispatched: with asynchronous dispatch
  the latter run ahead of the device, and the bar's rate and ETA would race and then stall at every fetch.
  """

  def __init__(self, config, writer, first_step: int):
    self.config, self.writer = config, writer
    self.window = []
    self.bar = tqdm.tqdm(total=config.max_steps, initial=first_step - 1, unit='step',
                         disable=not distributed.is_primary(), **progress.progress_kwargs())
    self.tic = time.time()
    self.skips = train_step_lib.SkipCounter(config.nonfinite_grad_policy, config.max_skipped_steps)
    self.losses, self.warned_stuck = [], False  # (end step, mean loss) of every window, for stuck.is_stuck.

  def add(self, step: int, stats) -> None:
    """Records a step's stats; under policy 'raise' it waits for the step to check it (no overlap of steps)."""
    if self.config.nonfinite_grad_policy == 'raise':
      self.skips.record(jax.device_get(stats), step)
    self.window.append((step, stats))

  def flush(self, step: int) -> None:
    """Fetches the window's stats, counts skipped updates, logs window means and throughput, updates the bar."""
    if not self.window:
      return
    host = jax.device_get(self.window)
    self.bar.update(len(host))  # These steps are done now.
    if self.config.nonfinite_grad_policy != 'raise':
      for s, stats in host:
        self.skips.record(stats, s)
    skipped = [(s, stats) for s, stats in host if stats['skipped']]
    if skipped:
      window = f'step {step}' if host[0][0] == step else f'steps {host[0][0]}-{step}'
      tqdm.tqdm.write(f'{window}: {len(skipped)} update(s) skipped (step {skipped[-1][0]}: '
                      f'non-finite {train_step_lib.skip_reason(skipped[-1][1])}); {self.skips.total} in all')
    elapsed = max(time.time() - self.tic, 1e-9)
    means = {k: float(np.mean([stats[k] for _, stats in host])) for k in host[-1][1]}
    means['rays_per_sec'] = self.config.batch_size * len(host) / elapsed
    means['steps_per_sec'] = len(host) / elapsed
    for k, v in means.items():
      self.writer.add_scalar(f'train/{k}', v, step)
    self.writer.add_scalar('train/skipped_steps', self.skips.total, step)
    self._warn_if_stuck(step, means['loss'])
    self.bar.set_postfix(loss=f'{means["loss"]:.4f}', psnr=f'{means["psnr"]:.2f}',
                         rays_per_s=f'{means["rays_per_sec"]:.0f}', skipped=self.skips.total, refresh=False)
    self.window, self.tic = [], time.time()

  def _warn_if_stuck(self, step: int, loss: float) -> None:
    """Records the window's mean loss; says once (process 0) when training looks stuck (see stuck.is_stuck)."""
    self.losses.append((step, loss))
    if not self.warned_stuck and stuck.is_stuck(self.losses, stuck.patience(self.config)):
      self.warned_stuck = True
      if distributed.is_primary():
        tqdm.tqdm.write(stuck.warning(self.config, self.losses))

  def close(self) -> None:
    """Closes the progress bar."""
    self.bar.close()


def preview(config, model, state, step: int, test_set, writer) -> None:
  """Renders one test view with the current parameters and logs its PSNR and images to tensorboard."""
  render_fn = inference.make_render_fn(config, model, sharding.local_copy(state.params), step)
  rays = jax.tree.map(lambda x: x[PREVIEW_INDEX], test_set.rays)
  rendering = inference.render_image(render_fn, rays, config.render_chunk_size)
  writer.add_scalar('test/psnr', metrics.psnr(rendering['rgb'], test_set.images[PREVIEW_INDEX]), step)
  for name, image in vis.visualize(rendering).items():
    writer.add_image(f'test/{name}', vis.to_uint8(image), step, dataformats='HWC')


def _example_rays(batcher):
  """A few rays of the first batch, to initialize the model's shapes."""
  return jax.tree.map(lambda x: x[:8], batcher(0).rays)


def _host_memory_named(config, batcher):
  """batcher(step) whose running out of host memory is an OutOfMemoryError naming Config.batch_size."""
  def batch(step: int) -> dict:
    with out_of_memory.naming_host_setting('drawing the training batch', f'Config.batch_size = {config.batch_size}'):
      return batcher(step)
  return batch


def _check_batch(config, mesh) -> None:
  """Raises ValueError naming Config.batch_size when it does not split evenly over the devices."""
  if config.batch_size % mesh.size:
    raise ValueError(f'Config.batch_size = {config.batch_size} must be a multiple of the number of devices '
                     f'({mesh.size})')
  patches = config.batch_size_random // config.patch_size**2
  if random_poses.needs_patches(config) and patches % mesh.size:
    raise ValueError(f'Config.batch_size_random = {config.batch_size_random} makes {patches} patches of '
                     f'{config.patch_size}x{config.patch_size}; expected a multiple of the number of devices '
                     f'({mesh.size}) so that every device gets whole patches')
  prior_patches = config.depth_prior_rays // config.depth_patch_size**2
  if depth_prior.any_on(config) and (prior_patches % mesh.size or config.depth_prior_rays % mesh.size):
    raise ValueError(f'Config.depth_prior_rays = {config.depth_prior_rays} makes {prior_patches} patches of '
                     f'Config.depth_patch_size = {config.depth_patch_size}; expected both counts to be multiples of '
                     f'the number of devices ({mesh.size})')


def train(config, stop_at_step: int = 0, stop: Optional[StopFlag] = None) -> TrainResult:
  """Trains up to Config.max_steps (or stop_at_step, if smaller and > 0), resuming from the newest checkpoint.

  The run directory is locked against a second training meanwhile (by process 0, when several processes train
  together). The final state is saved whether the loop ends or a signal stops it: SIGINT and SIGTERM are recorded
  in stop (default: a new StopFlag) from the first step until that save is committed, so that a second signal
  cannot cut it short.
  """
  with contextlib.ExitStack() as stack:
    distributed.on_primary(lambda: stack.enter_context(run_dir_lib.open_run(config)), 'opening the run directory')
    return _train_in(config, config.checkpoint_dir, stop_at_step, stop)


def _train_in(config, run_dir: str, stop_at_step: int, stop: Optional[StopFlag]) -> TrainResult:
  """train() inside the locked run directory; the settings are recorded once data and model are ready."""
  mesh = sharding.data_mesh()
  _check_batch(config, mesh)
  dataset = distributed.primary_first(lambda: datasets.load_dataset('train', config), 'loading the data')
  batcher = _host_memory_named(config, datasets.make_batcher(dataset, config))
  curve_views = learning_curve.load_views(config, evaluate.check_eval_inputs(config))
  init_key, train_key = random.split(random.PRNGKey(config.jax_rng_seed))
  cameras = camera_refinement.init(config, dataset) if config.optimize_cameras else None
  model, state = train_step_lib.create_train_state(config, init_key, _example_rays(batcher), cameras)
  distributed.on_primary(lambda: run_dir_lib.record_settings(run_dir, config), 'recording the settings')
  mngr = checkpoints.manager(run_dir, config.checkpoint_keep)
  state = sharding.replicate(state, mesh)
  restored = checkpoints.restore_latest(mngr, state)
  state = restored if restored is not None else state
  primary = distributed.is_primary()
  writer = event_file.EventWriter(os.path.join(run_dir, 'tensorboard')) if primary else NullWriter()
  moving = learning_curve.CurveCameras(config, dataset) if (
      curve_views is not None and primary and camera_evaluation.needs_alignment(config)) else None
  curve = learning_curve.Recorder(config, model, curve_views, run_dir, writer, int(state.step), moving) if (
      curve_views is not None and primary) else None
  last = min(config.max_steps, stop_at_step) if stop_at_step > 0 else config.max_steps
  with disk_full.stop_when_disk_full(run_dir), stop_on_signals(stop) as stop:
    try:
      with writer:
        state, skipped = _loop(config, model, state, batcher, mesh, train_key, mngr, writer, stop, last, curve)
      _save(mngr, state, curve)
    finally:
      mngr.wait_until_finished()
      mngr.close()
  if cameras is not None and primary:
    camera_export.write(run_dir, config, dataset, sharding.local_copy(state.cameras))
  return TrainResult(model, state, run_dir, stop.signum, skipped)


def _save(mngr, state, curve) -> None:
  """Saves a checkpoint of state (unless its step is saved already) and the learning curve's clock at its step."""
  checkpoints.save(mngr, state)
  if curve is not None:
    curve.checkpointed(int(state.step))


def _loop(config, model, state, batcher, mesh, key, mngr, writer, stop, last: int, curve):
  """Steps from state.step + 1 to last (or until a signal); saves every Config.checkpoint_every steps.

  curve: the learning_curve.Recorder of process 0 when Config.curve_every > 0, else None.

  Returns (state, number of skipped updates). The stats are fetched and checked before every save. Running out of
  accelerator memory is an OutOfMemoryError naming Config.batch_size, with XLA's estimate of the step.
  """
  step_fn = train_step_lib.make_train_step(config, model)
  first = int(state.step) + 1
  report = StepReport(config, writer, first)
  test_set = None
  needed = lambda: out_of_memory.compiled_bytes(step_fn, state, sharding.shard_batch(batcher(first), mesh), key)
  try:
    with out_of_memory.naming_setting('in the training step', f'Config.batch_size = {config.batch_size}', needed):
      for step in range(first, last + 1):
        batch, tic = sharding.shard_batch(batcher(step), mesh), time.perf_counter()
        state, stats = step_fn(state, batch, key)
        if step == first and curve is not None:  # The first call traces and compiles; later ones only dispatch.
          curve.compiled_step(time.perf_counter() - tic)
        report.add(step, stats)
        stopping = stop.stopping(step % config.print_every == 0 or step == last)
        if step % config.print_every == 0 or step == last or stopping:
          report.flush(step)
        if curve is not None and curve.due(step):  # Before a stop: the run resumes after this step.
          curve.record(step, state.params, getattr(state, 'cameras', None))
        if stopping:
          break
        if config.train_render_every > 0 and step % config.train_render_every == 0 and distributed.is_primary():
          test_set = test_set if test_set is not None else datasets.load_dataset('test', config)
          preview(config, model, state, step, test_set, writer)
        if step % config.checkpoint_every == 0 and step < last:
          report.flush(step)
          _save(mngr, state, curve)
  finally:
    report.close()
  return state, report.skips.total
