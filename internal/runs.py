"""The one door to runs: a Config parsed afresh, a run folder's own Config, and what the lab (lab/: studies, reports,
the GPU ledger) needs of a run: train and evaluate it, its fingerprint and step FLOPs, what it left on disk, its
scene's views and cameras, and the pictures drawn of them.

gin is global state, and besides the Config it holds the model's settings (MLP.*, MipNerfModel.*, the fused
layers' tiles), which a model reads when it is built and traced. `with fresh_config(files, bindings) as config:`
clears gin, parses the files and bindings and validates the Config, and clears gin again when the block ends, so
that no Config's settings leak into the next one and none is parsed over another's: build, train or evaluate the
model inside the block. A process that traces its models after the call returns (the viewer, the benchmarks) uses
bind_fresh, which clears gin first and leaves it bound to the Config's settings until the next one.
"""

import contextlib
import os
import statistics
import time
from typing import Callable, Iterator, List, NamedTuple, Optional

import gin
import jax
from jax import random
import numpy as np

from internal import config_loader
from internal import datasets
from internal.cameras import alignment
from internal.configs import Config
from internal.datasets import image_io, loader, packed
from internal.evaluation import camera_evaluation
from internal.evaluation import depth_metrics
from internal.evaluation import evaluate as evaluate_lib
from internal.evaluation import inference
from internal.evaluation import learning_curve
from internal.evaluation import metric_registry
from internal.evaluation import results
from internal.evaluation import vis
from internal.pipeline import loop
from internal.run import camera_export
from internal.run import checkpoints
from internal.run import run_dir as run_dir_lib
from internal.run import sharding
from internal.training import flops
from internal.training import train_step


# ------------------------------------------------------------------ settings

# Config fields that change nothing training computes (left out of a run's fingerprint): what may differ between a
# run and its resumption, or between two evaluations of one trained run.
NOT_FINGERPRINTED = run_dir_lib.NOT_FINGERPRINTED


def bind_fresh(gin_configs=(), gin_bindings=(), backend: str = '') -> Config:
  """The validated Config of gin files and bindings (its precision resolved for backend, '' = this process's),
  parsed with gin cleared first; gin stays bound to them (the model reads it) until the next Config is loaded."""
  gin.clear_config()
  return config_loader.load_config(list(gin_configs), list(gin_bindings), backend)


@contextlib.contextmanager
def fresh_config(gin_configs=(), gin_bindings=(), backend: str = '') -> Iterator[Config]:
  """Yields bind_fresh's Config of gin files and bindings; gin is cleared when the block ends."""
  try:
    yield bind_fresh(gin_configs, gin_bindings, backend)
  finally:
    gin.clear_config()


@contextlib.contextmanager
def run_config(run_dir: str) -> Iterator[Config]:
  """fresh_config of the settings a run folder records (its config.gin, which training writes)."""
  path = os.path.join(run_dir, run_dir_lib.GIN_FILE)
  if not os.path.isfile(path):
    raise FileNotFoundError(f'{path!r} does not exist; expected a run folder that train.py wrote (its settings)')
  with fresh_config([path]) as config:
    yield config


# ------------------------------------------------------------------ training and evaluating


def train(config: Config, stop: Optional[loop.StopFlag] = None) -> loop.TrainResult:
  """Trains the run of config, resuming from its newest checkpoint; stop: the StopFlag that records its signals."""
  return loop.train(config, stop=stop)


def stop_flag() -> loop.StopFlag:
  """A signal handler that only records the signal; `train` then saves a checkpoint and stops at the next step."""
  return loop.StopFlag()


def evaluate(config: Config) -> dict:
  """The metrics record of the run's newest checkpoint: the one its evaluation wrote, else evaluated now."""
  return evaluate_lib.existing_record(config) or evaluate_lib.evaluate(config)


def latest_step(run_dir: str) -> Optional[int]:
  """The newest step of a run folder with an intact checkpoint, None when it has none."""
  try:
    return checkpoints.latest_step(run_dir)
  except checkpoints.NoCheckpointError:
    return None


def fingerprint(config: Config) -> dict:
  """{'<Config|MLP|MipNerfModel|...>.<field>': value} of every setting that changes training (gin bound)."""
  return run_dir_lib.fingerprint(config)


def read_fingerprint(run_dir: str) -> Optional[dict]:
  """The fingerprint a run folder stored, None when it holds none."""
  return run_dir_lib.read_fingerprint(run_dir)


def differences(stored: dict, config: Config) -> str:
  """'name: stored -> current; ...' of the settings that differ between a stored fingerprint and config ('': none)."""
  return run_dir_lib.differences(stored, config)


def step_flops(config: Config) -> float:
  """XLA's flop count of one train step of config's model and batch."""
  return flops.train_step_flops(config)


def _timed(fn) -> tuple:
  """(fn()'s result with every array ready, seconds it took)."""
  tic = time.perf_counter()
  result = jax.block_until_ready(fn())
  return result, time.perf_counter() - tic


def measure(config: Config, probe_steps: int) -> dict:
  """{'setup_seconds' (data, model, first step with compilation), 'step_seconds' (median of probe_steps),
  'view_seconds' (one test view at Config.eval_factor, compiled), 'eval_views', 'curve_views'} of a config."""
  tic = time.perf_counter()
  batcher = datasets.make_batcher(datasets.load_dataset('train', config), config)
  mesh = sharding.data_mesh()
  model, state = train_step.create_train_state(config, random.PRNGKey(config.jax_rng_seed),
                                               jax.tree.map(lambda x: x[:8], batcher(0).rays))
  state, step_fn, key = sharding.replicate(state, mesh), train_step.make_train_step(config, model), random.PRNGKey(0)
  batch = lambda step: sharding.shard_batch(batcher(step), mesh)
  state, _ = _timed(lambda: step_fn(state, batch(1), key))[0]
  setup = time.perf_counter() - tic
  times = []
  for step in range(2, 2 + probe_steps):
    (state, _), seconds = _timed(lambda s=step: step_fn(state, batch(s), key))
    times.append(seconds)
  test_set = datasets.load_dataset('test', config)
  render_fn = inference.make_render_fn(config, model, sharding.local_copy(state.params), probe_steps + 1)
  view = jax.tree.map(lambda x: x[0], test_set.rays)
  render = lambda: inference.render_image(render_fn, view, config.render_chunk_size)
  _timed(render)
  curve_views = len(config.curve_test_ids) if config.curve_every else 0
  return {'setup_seconds': setup, 'step_seconds': statistics.median(times), 'view_seconds': _timed(render)[1],
          'eval_views': len(evaluate_lib.select_positions(config, len(test_set.ids))), 'curve_views': curve_views}


# ------------------------------------------------------------------ what a run left

CURVE_FILE = learning_curve.CSV_FILE    # In the run folder: the learning curve's rows.
CLOCK_FILE = learning_curve.CLOCK_FILE  # In the run folder: the curve's clock at the newest checkpoint.


def eval_dir(run_dir: str, step: int) -> str:
  """The folder a run's evaluation at step writes (<run_dir>/test_preds_step_<step>)."""
  return evaluate_lib.output_dir(run_dir, step)


def metrics_record(run_dir: str, step: int) -> dict:
  """The metrics record ({'means', 'per_image', ...}) that a run's evaluation at step wrote (its metrics.json)."""
  return results.read_record(os.path.join(eval_dir(run_dir, step), results.METRICS_FILENAME))


def curve_path(run_dir: str) -> str:
  """The learning curve's CSV of a run folder."""
  return learning_curve.csv_path(run_dir)


def read_curve(path: str) -> List[dict]:
  """The rows of a learning curve's CSV ({'step', 'seconds', 'psnr', ...}); [] when it does not exist."""
  return learning_curve.read_rows(path)


def depth_file(eval_dir_path: str, view_id: int) -> str:
  """The rendered depth an evaluation kept of a test view (depth_<id>.npz, its 'distance')."""
  return depth_metrics.depth_file(eval_dir_path, view_id)


def lower_is_better() -> dict:
  """{metric name: whether lower is better} of every metric a metrics.json may hold."""
  return metric_registry.lower_is_better()


# ------------------------------------------------------------------ scenes and cameras


class TestViews(NamedTuple):
  """A scene's test views as evaluation loads them: ids, images [N,H,W,3], exact depths [N,H,W] (None where the
  scene has none), and world_depth(position, rendered distance [H,W]) -> world depth [H,W], as depth_mae reads it."""
  ids: list
  images: np.ndarray
  depths: Optional[np.ndarray]
  world_depth: Callable


def test_views(config: Config) -> TestViews:
  """The test views of config's scene, with exact depths where the scene has them."""
  test_set = datasets.load_dataset('test', config, ground_truth=True)
  ndc = loader.REGISTRY[loader.filed_as(config)[0]].ndc(config)
  return TestViews([int(i) for i in test_set.ids], test_set.images, test_set.depths,
                   lambda i, distance: depth_metrics.world_depth(test_set, i, distance, ndc))


def training_views(config: Config) -> datasets.Dataset:
  """The training split of config's scene (images, cameras, rays)."""
  return datasets.load_dataset('train', config)


def pack_test_views(path: str) -> tuple:
  """(test view ids, their images [N,H,W,3]) of a packed scene (tools.pack_scene)."""
  meta, arrays = packed.read_pack(path)
  return meta['splits']['test']['ids'], packed.decode(arrays, 'test/images')


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
  """An image [H,W,C] at 1/factor of its size, as the loaders make smaller images (the released resize)."""
  return image_io.downsample(image, factor, 'released')


def cameras_file(run_dir: str) -> str:
  """The given and refined training cameras a refining run wrote after training (cameras/cameras.json)."""
  return os.path.join(run_dir, camera_export.FOLDER, 'cameras.json')


def reference_cameras(config: Config, train_set: datasets.Dataset) -> tuple:
  """(reference training cameras [N,3,4], their camera distance, whether the given cameras share their frame)."""
  return camera_evaluation.reference_cameras(config, train_set)


def similarity(source: np.ndarray, target: np.ndarray) -> alignment.Similarity:
  """The similarity that best takes cameras source [N,3,4] onto target [N,3,4] (.cameras(c2w) applies it)."""
  return alignment.fit(source, target)


def own_axes_turns(cameras: np.ndarray, reference: np.ndarray) -> np.ndarray:
  """[N,3] rotation errors (degrees) of cameras against reference, both in one frame, in each reference camera's own
  axes (alignment.own_axes_turns)."""
  return alignment.own_axes_turns(cameras, reference)


def camera_errors(cameras: np.ndarray, reference: np.ndarray, distance: float, align: bool = True) -> dict:
  """{'rotation_deg', 'translation'} per camera of cameras against reference (translation of the distance)."""
  return alignment.errors(cameras, reference, distance, align)


# ------------------------------------------------------------------ checkpoints as saved


def saved_tree(run_dir: str, step: int) -> dict:
  """The tree of a run folder's checkpoint at step as saved ({'params', ...}; no template needed)."""
  import orbax.checkpoint as ocp  # pylint: disable=import-outside-toplevel
  return ocp.StandardCheckpointer().restore(os.path.abspath(os.path.join(run_dir, checkpoints.CHECKPOINT_SUBDIR,
                                                                         str(step), checkpoints.ITEM)))


def nonfinite_leaves(tree) -> list:
  """The '/'-joined paths of a tree's leaves that hold a non-finite value."""
  return checkpoints.nonfinite_leaves(tree)


def write_model_run(config: Config, params: dict, step: int) -> None:
  """Config.checkpoint_dir as a run folder holding params ({'/'-joined key: array}, as saved_tree's 'params' are
  flattened) at step, with fresh optimizer moments: for evaluation and rendering, not for training on."""
  rays = jax.tree.map(lambda x: x[0, 0, :8], training_views(config).rays)  # As eval's template.
  _, state = train_step.create_train_state(config, random.PRNGKey(config.jax_rng_seed), rays)
  flat = dict(params)
  restored = jax.tree_util.tree_map_with_path(lambda p, x: flat.pop('/'.join(k.key for k in p)).astype(x.dtype),
                                              state.params)
  run_dir_lib.record_settings(run_dir_lib.prepare_run_dir(config), config)
  mngr = checkpoints.manager(config.checkpoint_dir, 1)
  checkpoints.save(mngr, state.replace(params=restored, step=np.asarray(step, np.asarray(state.step).dtype)))
  mngr.wait_until_finished()
  mngr.close()


# ------------------------------------------------------------------ pictures

save_png = vis.save_png          # A float [H,W,3] image in [0, 1] as a full-colour PNG (data, e.g. a render).
save_picture = vis.save_picture  # A picture meant for reading as a 256-colour PNG.
save_figure = vis.save_figure    # A matplotlib figure, labelled, as a picture.
line_figure = vis.line_figure    # A figure of lines {label: [(x, y)]}.
colorize_depth = vis.colorize_depth
grid = vis.grid                  # Tiles with column and row titles as one picture.
