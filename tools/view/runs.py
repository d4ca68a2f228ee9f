"""A run the viewer shows: its settings, scene and cameras, and its newest checkpoint rendering any rays.

Each run is loaded with its own gin state (gin.clear_config, then its files and bindings): the model reads gin when
it is built, and two runs of a comparison have different models. Renders go in chunks of a power of two rays (at
least MIN_CHUNK, at most Config.render_chunk_size), padded as render.py pads its last chunk: a handful of compiled
shapes serve every frame size the viewer asks for. A newer checkpoint (train.py still writing them) replaces the
parameters in place; the compiled renderer is kept.
"""

import dataclasses
import os
import threading
import warnings

import gin
import jax
import numpy as np

from internal import cli
from internal import config_loader
from internal import datasets
from internal import rays as rays_lib
from internal.datasets import base, loader
from internal.evaluation import camera_evaluation, inference
from internal.run import checkpoints, run_dir as run_dir_lib
from internal.training import camera_refinement
from tools.view import cameras

MIN_CHUNK = 256
PATH_FRAMES = 60  # Render-path frames drawn (the path's shape, not every frame render.py renders).
PATH_ROWS = 16    # About this many rows a frame: only the frames' centres are drawn.


def chunk_size(num_rays: int, largest: int) -> int:
  """Rays a compiled render call takes for a frame of num_rays: the power of two >= num_rays, within
  [MIN_CHUNK, largest] (largest itself when smaller than MIN_CHUNK)."""
  size = MIN_CHUNK
  while size < num_rays:
    size *= 2
  return min(size, largest)


@dataclasses.dataclass
class CameraSet:
  """Cameras as the viewer draws them: camera-to-world [N,3,4] with OpenCV axes, inverse intrinsics [N,3,3], and
  the size of their images (height, width)."""
  camtoworlds: np.ndarray
  pixtocams: np.ndarray
  size: tuple


class Run:
  """One trained run: config, run folder, scene (training and test splits, how rays follow from cameras) and its
  newest checkpoint's parameters and step; render(rays) renders with them."""

  def __init__(self, config, run_dir: str, model, state, train_set, test_set):
    self.config, self.run_dir, self.model = config, run_dir, model
    self.train_set, self.test_set = train_set, test_set
    self.space = train_set.space  # How rays follow from cameras in the scene (its loader set it), and its axes.
    self.opengl = self.space.opengl
    self._compiled = inference.compile_render(config, model)
    self._lock = threading.Lock()
    self._chunks = set()  # The chunk sizes rendered so far: each compiled once.
    self._reference = None  # The reference training cameras of test_cameras, where it needs them.
    self._use(state)

  def _use(self, state) -> None:
    """Makes state (a TrainState) the one rendered."""
    render_fn = inference.make_render_fn(self.config, self.model, state.params, int(state.step),
                                         compiled=self._compiled)
    with self._lock:
      self.state, self.render_fn = state, render_fn

  @property
  def step(self) -> int:
    return int(self.state.step)

  def reload(self) -> bool:
    """Loads the newest intact checkpoint when it is newer than the one shown; whether it was."""
    if checkpoints.latest_step(self.run_dir) <= self.step:
      return False
    self._use(checkpoints.load_latest(self.run_dir, self.state))
    return True

  def compiled_shapes(self) -> frozenset:
    """The chunk sizes rendered (so compiled) so far."""
    return frozenset(self._chunks)

  def render(self, rays) -> dict:
    """{'rgb', 'acc', 'distance_mean', 'distance_median'} numpy [H, W, ...] of rays [H, W, ...] with the newest
    loaded checkpoint, in chunks of chunk_size rays."""
    with self._lock:
      render_fn = self.render_fn
    shape = rays.origins.shape[:-1]
    flat = rays_lib.map_rays(lambda x: np.reshape(x, (-1, x.shape[-1])), rays)
    count = flat.origins.shape[0]
    chunk = chunk_size(count, self.config.render_chunk_size)
    pad = -count % chunk
    padded = rays_lib.map_rays(lambda x: np.pad(x, ((0, pad), (0, 0)), mode='edge'), flat)
    out = inference.render_image(render_fn, padded, chunk)
    self._chunks.add(chunk)
    return {k: v[:count].reshape(shape + v.shape[1:]) for k, v in out.items()}

  def training_cameras(self) -> dict:
    """{'given': CameraSet} of the training views as loaded, and 'refined' with camera refinement."""
    given = np.asarray(self.train_set.camtoworlds, np.float64)
    size = (self.train_set.height, self.train_set.width)
    sets = {'given': CameraSet(cameras.to_opencv(given, self.opengl), self.train_set.pixtocams, size)}
    if self.config.optimize_cameras:
      refined = camera_refinement.refined_cameras(self.state.cameras, given)
      sets['refined'] = CameraSet(cameras.to_opencv(refined, self.opengl), self.train_set.pixtocams, size)
    return sets

  def test_cameras(self) -> CameraSet:
    """The test views' cameras in the frame the model was trained in (carried there by the similarity evaluation
    uses when the training cameras were refined or perturbed)."""
    c2w = np.asarray(self.test_set.camtoworlds, np.float64)
    if camera_evaluation.needs_alignment(self.config):
      if self._reference is None:  # The loader's own training cameras: they load once.
        self._reference = camera_evaluation.reference_cameras(self.config, self.train_set)
      trained = camera_evaluation.training_cameras(self.train_set, getattr(self.state, 'cameras', None),
                                                   self._reference)
      c2w = camera_evaluation.test_similarity(trained).cameras(c2w)
    return CameraSet(cameras.to_opencv(c2w, self.opengl), self.test_set.pixtocams,
                     (self.test_set.height, self.test_set.width))

  def path_centres(self) -> np.ndarray:
    """[F,3] centres of the render path's frames (at most PATH_FRAMES of them, made at a small size)."""
    small = dataclasses.replace(self.config, render_path_frames=min(self.config.render_path_frames, PATH_FRAMES))
    if self.config.dataset_loader != 'packed':  # A pack holds its path at one size.
      shrink = max(self.test_set.height // PATH_ROWS, 1)
      small = dataclasses.replace(small, render_factor=base.render_factor(self.config) * shrink)
    with warnings.catch_warnings():
      warnings.simplefilter('ignore')  # An LLFF scene warns that it builds images of that size from a finer one.
      return cameras.path_centres(datasets.render_path_rays(small), self.space)


def load(gin_configs, gin_bindings) -> Run:
  """The Run of gin configs (none: the demo's FreeNeRF) and bindings; the same errors as eval.py for a missing
  run, a run trained with other settings or missing data."""
  gin.clear_config()
  config = config_loader.load_config(list(gin_configs) or cli.DEMO_CONFIGS, gin_bindings)
  run_dir = run_dir_lib.check_run_dir(config)
  checkpoints.latest_step(run_dir)  # Names the folder when it holds no checkpoint, before the data loads.
  train_set = datasets.load_dataset('train', config)
  test_set = datasets.load_dataset('test', config)
  example = jax.tree.map(lambda x: x[0, 0, :8], train_set.rays)
  model, state = checkpoints.restore_model(config, run_dir, example, train_set)
  return Run(config, run_dir, model, state, train_set, test_set)


def check_same_scene(first: Run, second: Run) -> None:
  """ValueError naming --compare_configs / --compare_bindings when the second run is of another scene than the
  first (a comparison draws both in one world)."""
  scenes = [loader.filed_as(run.config) + (os.path.realpath(run.config.data_dir),) for run in (first, second)]
  if scenes[0] != scenes[1]:
    raise ValueError(f'--compare_configs / --compare_bindings: the second run {second.run_dir!r} is of scene '
                     f'{scenes[1][1]!r} in {scenes[1][2]!r}, the first {first.run_dir!r} of {scenes[0][1]!r} in '
                     f'{scenes[0][2]!r}; compare runs of one scene')
