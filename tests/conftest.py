"""Shared test fixtures: a clean gin state per test, small random ray bundles, the shared data folder."""

import pathlib

import gin
import numpy as np
import pytest

from internal import rays as rays_lib

SHARED_DATA = pathlib.Path(__file__).resolve().parents[2] / 'shared' / 'data'


@pytest.fixture(autouse=True)
def clean_gin():
  """Every test starts and ends with no gin bindings."""
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
