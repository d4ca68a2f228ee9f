"""Chunked rendering equals one unchunked call, also when the ray count is not a multiple of the chunk."""

import jax
import numpy as np
import pytest
from jax import random

from conftest import random_rays
from internal import config_loader
from internal.evaluation import inference
from internal.models import mip_nerf
from internal import rays as rays_lib

TINY = ['MLP.net_depth = 2', 'MLP.net_width = 16', 'MLP.net_width_viewdirs = 8',
        'MipNerfModel.num_samples = 8', 'Config.freq_reg = True', 'Config.freq_reg_end = 10']


@pytest.fixture
def render_setup():
  """(render_fn, rays [2, 5, ...], unchunked fine-level outputs [10, ...]) of a tiny model at step 4."""
  config = config_loader.load_config([], TINY)
  flat = random_rays(0, 10)
  model, variables = mip_nerf.construct_model(random.PRNGKey(0), flat, white_background=False)
  render_fn = inference.make_render_fn(config, model, variables['params'], step=4)
  whole = jax.device_get(render_fn(flat))
  return render_fn, rays_lib.map_rays(lambda x: x.reshape(2, 5, -1), flat), whole


@pytest.mark.parametrize('chunk_size', [3, 4, 5, 10, 64])  # 3 and 4 pad the last chunk; 64 > the ray count.
def test_chunked_equals_unchunked(render_setup, chunk_size):
  render_fn, rays, whole = render_setup
  image = inference.render_image(render_fn, rays, chunk_size)
  assert set(image) == set(inference.OUTPUT_KEYS)
  for key in inference.OUTPUT_KEYS:
    assert image[key].shape == (2, 5) + whole[key].shape[1:], key
    np.testing.assert_allclose(image[key].reshape(whole[key].shape), whole[key], rtol=1e-5, atol=1e-6,
                               err_msg=key)


def test_one_compilation_renders_every_step_with_its_masks():
  config = config_loader.load_config([], TINY)
  rays = random_rays(1, 12)
  model, variables = mip_nerf.construct_model(random.PRNGKey(0), rays, white_background=False)
  compiled = inference.compile_render(config, model)
  shared = {s: jax.device_get(inference.make_render_fn(config, model, variables['params'], s, compiled=compiled)(rays))
            for s in (2, 8)}
  for step, outputs in shared.items():
    fresh = jax.device_get(inference.make_render_fn(config, model, variables['params'], step)(rays))
    np.testing.assert_allclose(outputs['rgb'], fresh['rgb'], rtol=1e-6, atol=1e-7)
  assert np.abs(shared[2]['rgb'] - shared[8]['rgb']).max() > 1e-4   # The frequency mask opens in between.
  assert compiled._cache_size() == 1                                  # pylint: disable=protected-access
