"""Shared test fixtures: a clean gin state per test, small random ray bundles, toy scenes, the shared data folder.

Also points JAX's persistent compilation cache at one folder for every test (and the subprocesses some start).
"""

import json
import os
import pathlib
import tempfile

import gin
import jax
import numpy as np
import pytest
from PIL import Image

from internal import rays as rays_lib

SHARED_DATA = pathlib.Path(__file__).resolve().parents[2] / 'shared' / 'data'
JAX_CACHE = os.path.join(tempfile.gettempdir(), 'freenerf_test_jax_cache')
jax.config.update('jax_compilation_cache_dir', JAX_CACHE)
jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.)
N_LLFF, H, W = 10, 6, 8  # The toy LLFF scene: views, image height and width.
# XLA's GPU code may round float32 arithmetic differently from its CPU code (division, fused multiply-adds): seen on
# an H200, a mask weight 231/1000 one unit in the last place off.
ACCELERATOR_ULPS = 2


@pytest.fixture(autouse=True)
def clean_gin():
  """Every test starts and ends with no gin bindings (unlocked: a test may parse its own); a test loads its Configs
  through the door, runs.bind_fresh, which clears gin first."""
  gin.clear_config()
  yield
  gin.clear_config()


def random_rays(seed: int, num_rays: int, near: float = 2., far: float = 6.) -> rays_lib.Rays:
  """Rays [num_rays, ...] from points around the origin looking at it, float32."""
  rng = np.random.default_rng(seed)
  origins = rng.normal(size=(num_rays, 3)) * 0.2 + np.array([0., 0., 4.])
  directions = -origins + rng.normal(size=(num_rays, 3)) * 0.1
  directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
  ones = np.ones((num_rays, 1))
  rays = rays_lib.Rays(origins, directions, directions, ones * 0.002, ones, ones * near, ones * far)
  return rays_lib.map_rays(lambda x: x.astype(np.float32), rays)


@pytest.fixture(scope='session')
def scene_dir(tmp_path_factory):
  """Folder of the generated scene (written on first load and shared by every test of the session)."""
  return tmp_path_factory.getbasetemp() / 'generated_scene'


def assert_float32_exact(actual, expected):
  """Bit for bit equal on the CPU; within ACCELERATOR_ULPS units in the last place on an accelerator."""
  if jax.default_backend() == 'cpu':
    np.testing.assert_array_equal(actual, expected)
  else:
    actual = np.asarray(actual, np.float32)
    np.testing.assert_array_max_ulp(actual, np.broadcast_to(np.asarray(expected, np.float32), actual.shape),
                                    ACCELERATOR_ULPS)


def save_png(path, array):
  os.makedirs(os.path.dirname(path), exist_ok=True)
  Image.fromarray(array).save(path)


def noise(seed, shape):
  return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


@pytest.fixture
def llff_root(tmp_path):
  """<tmp>/scenes/toy: poses_bounds.npy (10 cameras along x, looking down -z) and images_8/ of 6x8 PNGs."""
  scene = tmp_path / 'scenes' / 'toy'
  rows = []
  for i in range(N_LLFF):
    pose = np.array([[0., 1., 0., .1 * i], [-1., 0., 0., 0.], [0., 0., 1., 0.]])   # [down, right, back] axes.
    rows.append(np.concatenate([np.concatenate([pose, [[H * 8.], [W * 8.], [50.]]], 1).ravel(), [2., 20.]]))
    save_png(str(scene / 'images_8' / f'img{i:02d}.png'), noise(i, (H, W, 3)))
  np.save(scene / 'poses_bounds.npy', np.array(rows))
  return tmp_path / 'scenes'


@pytest.fixture
def blender_root(tmp_path):
  """<tmp>/scenes/toy: 3 train frames and 16 test frames (test[::8] = r_0, r_8) of 8x8 RGBA PNGs."""
  scene = tmp_path / 'scenes' / 'toy'
  for split, n in (('train', 3), ('test', 16)):
    frames = [{'file_path': f'./{split}/r_{i}', 'transform_matrix': np.eye(4).tolist()} for i in range(n)]
    (scene / split).mkdir(parents=True)
    (scene / f'transforms_{split}.json').write_text(json.dumps({'camera_angle_x': .7, 'frames': frames}))
    for i in range(n):
      save_png(str(scene / split / f'r_{i}.png'), noise(i, (8, 8, 4)))
  return tmp_path / 'scenes'
