"""The xyz ablation (MLP.point_identity / NerfMLP.point_identity): the raw coordinates leave the point encoding."""

import gin
import numpy as np
import pytest
from jax import random

from conftest import random_rays
from internal import runs
from internal.configs import Config
from internal.models import freq_schedule
from internal.models import mip_nerf
from internal.models import nerf
from internal.run import run_dir

MIP_TINY = ['MLP.net_depth = 4', 'MLP.net_width = 16', 'MLP.net_width_viewdirs = 8', 'MLP.skip_layer = 2',
            'MipNerfModel.num_samples = 4']
NERF_TINY = ['NerfMLP.net_depth = 3', 'NerfMLP.net_width = 16', 'NerfMLP.net_width_viewdirs = 8',
             'NerfMLP.skip_layer = 1', 'NerfModel.num_coarse_samples = 4', 'NerfModel.num_fine_samples = 4']
# Per model: tiny bindings, its gin MLP name, construct_model, the trunk layer after which the skip concatenates,
# where the encoding sits in that concatenation (mip-NeRF: after the hidden units; NeRF: before them), its width.
MODELS = {'mipnerf': (MIP_TINY, 'MLP', mip_nerf.construct_model, 2, 'after', 99),
          'nerf': (NERF_TINY, 'NerfMLP', nerf.construct_model, 1, 'before', 63)}


def _build(name, point_identity):
  tiny, mlp_name, construct, *_ = MODELS[name]
  runs.bind_fresh([], tiny + [f'{mlp_name}.point_identity = {point_identity}'])
  return construct(random.PRNGKey(0), random_rays(0, 3), white_background=True)


def _identity_rows(name, layer: str):
  """Rows of layer's kernel that multiply the raw coordinates (Dense_0, or the skip layer)."""
  _, _, _, skip, place, _ = MODELS[name]
  if layer == 'Dense_0' or place == 'before':
    return slice(0, 3)
  return slice(16, 19)  # After the 16 hidden units of the tiny trunk.


@pytest.mark.parametrize('name', MODELS)
def test_without_xyz_the_model_equals_the_full_one_with_zero_weights_on_xyz(name):
  _, _, _, skip, _, full_width = MODELS[name]
  model_off, variables_off = _build(name, False)
  model_on, variables_on = _build(name, True)
  for mlp in variables_on['params']:
    params_on, params_off = variables_on['params'][mlp], variables_off['params'][mlp]
    assert params_on['Dense_0']['kernel'].shape[0] == full_width
    assert params_off['Dense_0']['kernel'].shape[0] == full_width - 3  # The MLP's input narrows by 3.
    for layer in ('Dense_0', f'Dense_{skip + 1}'):
      rows = _identity_rows(name, layer)
      kernel = np.array(params_on[layer]['kernel'])
      kernel[rows] = 0.  # The full model, blind to xyz ...
      params_on[layer]['kernel'] = kernel
      params_off[layer]['kernel'] = np.delete(kernel, np.arange(kernel.shape[0])[rows], axis=0)
      params_off[layer]['bias'] = params_on[layer]['bias']
    for layer in params_on:  # ... and the model without xyz share every other weight.
      if layer not in ('Dense_0', f'Dense_{skip + 1}'):
        params_off[layer] = params_on[layer]
  rays = random_rays(1, 6)
  off, _ = model_off.apply(variables_off, None, rays)
  on, _ = model_on.apply(variables_on, None, rays)
  for level_off, level_on in zip(off, on):
    np.testing.assert_allclose(level_off['rgb'], level_on['rgb'], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(level_off['weights'], level_on['weights'], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize('name,width', [('mipnerf', 96), ('nerf', 60)])
def test_without_xyz_the_mask_keeps_the_schedule_of_every_frequency(name, width):
  # Released layout, T = 99 (mip-NeRF: 33 chunks of 3; NeRF: 21): at step 3 the full pointer is 33 * 3/99 + 1 = 2
  # for mip-NeRF, chunks 0 (xyz) and 1 (sin of degree 0) open; dropped xyz leaves sin degree 0 open, nothing else.
  model, variables = _build(name, False)
  end = 99 if name == 'mipnerf' else 63
  config = Config(model=name, freq_reg=True, freq_reg_end=end)
  point, view = (np.asarray(m) for m in freq_schedule.model_masks(config, model, 3))
  assert point.shape == (width,) and view.shape == (27,)
  np.testing.assert_array_equal(point[:3], 1.)
  assert np.all(point[3:] < 1e-7)
  assert np.all(np.asarray(freq_schedule.model_masks(config, model, 0)[0]) < 1e-7)  # Nothing before step 1.
  renderings, _ = model.apply(variables, None, random_rays(2, 4), point, view)
  assert np.all(np.isfinite(renderings[-1]['rgb']))


@pytest.mark.parametrize('name', MODELS)
def test_the_setting_is_fingerprinted_and_older_runs_read_as_with_xyz(name):
  _, mlp_name, *_ = MODELS[name]
  config = Config(model=name)
  gin.parse_config([f'{mlp_name}.point_identity = False'])
  off = run_dir.fingerprint(config)
  assert off[f'{mlp_name}.point_identity'] is False
  with runs.fresh_config():  # Nothing bound: the setting at its default.
    older = {k: v for k, v in run_dir.fingerprint(config).items() if k != f'{mlp_name}.point_identity'}
  assert run_dir.differences(older, config) == ''  # A run from before the setting existed had xyz.
  gin.parse_config([f'{mlp_name}.point_identity = False'])
  assert f'{mlp_name}.point_identity: True -> False' in run_dir.differences(older, config)
