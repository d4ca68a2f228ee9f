"""Config.precision: float32 is the exact float32 path, bfloat16 stays close with float32 params and outputs."""

import itertools

import gin
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import random

from conftest import random_rays
from internal import config_loader
from internal import configs
from internal.datasets.batching import Batch
from internal.models import mip_nerf
from internal.models import precision
from internal.run import run_dir
from internal.training import train_step as ts

TINY = ['MLP.net_depth = 3', 'MLP.net_width = 32', 'MLP.skip_layer = 2', 'MLP.net_width_viewdirs = 16',
        'MipNerfModel.num_samples = 8', 'MLP.density_noise = 1.0']


def _config(name):
  return configs.Config(precision=name, freq_reg=True, freq_reg_end=10, occ_reg_loss_mult=0.01,
                        grad_max_norm=0.1, white_background=False)


def _render(name, params, rays):
  """Fine-level outputs of the tiny model at one precision, with given (float32) params."""
  model = mip_nerf.MipNerfModel(white_background=False, precision=name)
  return model.apply({'params': params}, None, rays)[0][-1]


def _dot_precisions(name, encoding=False):
  """(matmul precision, operand dtype) of every dot_general of the MLP (or of the encodings, whose matmuls lift
  the 3 coordinates) in the tiny model's forward pass."""
  gin.parse_config(TINY)
  rays = random_rays(0, 4)
  model, variables = mip_nerf.construct_model(random.PRNGKey(0), rays, False, name)
  jaxpr = jax.make_jaxpr(lambda v: model.apply(v, None, rays))(variables)
  return {(str(e.params['precision']), str(e.invars[0].aval.dtype))
          for e in _equations(jaxpr.jaxpr)
          if e.primitive.name == 'dot_general' and (e.invars[1].aval.shape[0] == 3) == encoding}


def _equations(jaxpr):
  """Every equation of jaxpr and of the jaxprs nested in its equations (custom derivatives, calls)."""
  for eqn in jaxpr.eqns:
    yield eqn
    for value in eqn.params.values():
      inner = getattr(value, 'jaxpr', value)
      if hasattr(inner, 'eqns'):
        yield from _equations(inner)


def test_every_matmul_uses_the_chosen_precision_and_dtype():
  assert _dot_precisions('float32') == {('(Precision.HIGHEST, Precision.HIGHEST)', 'float32')}
  assert _dot_precisions('default') == {('None', 'float32')}
  assert _dot_precisions('bfloat16') == {('None', 'bfloat16')}
  for name in precision.PRECISIONS:  # The encodings stay exact float32 (their matmuls multiply by powers of 2).
    assert _dot_precisions(name, encoding=True) == {('(Precision.HIGHEST, Precision.HIGHEST)', 'float32')}


@pytest.mark.parametrize('name', precision.PRECISIONS)
def test_train_step_runs_and_keeps_float32_params(name):
  gin.parse_config(TINY)
  config = _config(name)
  rays = random_rays(0, 64)
  model, state = ts.create_train_state(config, random.PRNGKey(0), rays)
  batch = Batch(rays=rays, rgb=np.random.default_rng(0).uniform(size=(64, 3)).astype(np.float32))
  before = jax.tree.map(np.asarray, state.params)
  new, stats = ts.make_train_step(config, model)(state, batch, random.PRNGKey(1))
  assert bool(stats['grads_finite']) and np.isfinite(float(stats['loss']))
  assert stats['loss'].dtype == jnp.float32
  leaves = jax.tree.leaves(new.params) + jax.tree.leaves(new.opt_state)
  assert all(x.dtype in (jnp.float32, jnp.int32) for x in leaves)
  assert any(np.any(np.asarray(a) != b)  # The update moved the parameters.
             for a, b in zip(jax.tree.leaves(new.params), jax.tree.leaves(before)))


def _float32_and_default():
  """Fine-level outputs of the tiny model at Config.precision 'float32' and 'default', same params and rays."""
  gin.parse_config(TINY)
  rays = random_rays(1, 32)
  _, variables = mip_nerf.construct_model(random.PRNGKey(0), rays, False)
  return (_render(n, variables['params'], rays) for n in ('float32', 'default'))


@pytest.mark.skipif(jax.default_backend() != 'cpu', reason='an accelerator has its own default matmul precision')
def test_float32_equals_the_backend_default_path_on_cpu():
  # On CPU the default matmul precision is full float32, the path of the code before Config.precision.
  f32, default = _float32_and_default()
  for key in ('rgb', 'acc', 'distance_mean'):
    np.testing.assert_array_equal(f32[key], default[key])


@pytest.mark.skipif(jax.default_backend() == 'cpu', reason='on the CPU default is float32 (the test above)')
def test_default_stays_near_float32_on_an_accelerator():
  # On an NVIDIA GPU 'default' multiplies in TF32 (10-bit mantissa): seen on an H200, rgb 2.5e-4 relative off.
  f32, default = _float32_and_default()
  for key in ('rgb', 'acc', 'distance_mean'):
    np.testing.assert_allclose(default[key], f32[key], rtol=1e-2, atol=1e-3)


def test_bfloat16_close_to_float32_with_float32_outputs():
  gin.parse_config(TINY)
  rays = random_rays(2, 32)
  _, variables = mip_nerf.construct_model(random.PRNGKey(0), rays, False)
  f32, bf16 = (_render(n, variables['params'], rays) for n in ('float32', 'bfloat16'))
  for key in ('rgb', 'acc', 'weights', 'distance_mean'):
    assert bf16[key].dtype == jnp.float32, key
  difference = np.abs(np.asarray(bf16['rgb']) - np.asarray(f32['rgb']))
  assert 0 < difference.max() < 2e-2  # Rounded (so not the float32 path) but close.
  np.testing.assert_allclose(bf16['acc'], f32['acc'], atol=2e-2)


def test_bad_precision_is_a_clear_error():
  with pytest.raises(ValueError, match=r"Config.precision = 'fp16'; expected one of \['auto', 'float32'"):
    config_loader.validate(configs.Config(precision='fp16'))
  with pytest.raises(ValueError, match='Config.precision'):
    mip_nerf.construct_model(random.PRNGKey(0), random_rays(0, 2), False, 'fp16')


def test_auto_is_float32_on_a_cpu_and_bfloat16_on_an_accelerator_and_runs_record_the_resolved_one():
  expected = 'float32' if jax.default_backend() == 'cpu' else 'bfloat16'
  assert precision.resolve('auto') == expected and precision.settings('auto') == precision.settings(expected)
  assert configs.Config().precision == 'auto'
  assert config_loader.load_config([], []).precision == expected
  gin.clear_config()
  assert config_loader.load_config([], ["Config.precision = 'default'"]).precision == 'default'
  # For another machine (a cluster estimate printed on a CPU for GPUs): resolved for its backend.
  gin.clear_config()
  assert config_loader.load_config([], [], backend='gpu').precision == precision.resolve('auto', 'gpu') == 'bfloat16'
  assert precision.resolve('auto', 'cpu') == 'float32' and precision.resolve('default', 'gpu') == 'default'


def test_precision_comes_from_config_only_and_is_fingerprinted():
  with pytest.raises(ValueError, match='precision'):
    gin.parse_config(["MLP.precision = 'bfloat16'"])
  keys = run_dir.fingerprint(configs.Config(precision='bfloat16'))
  assert keys['Config.precision'] == 'bfloat16'
  assert 'MLP.precision' not in keys and 'MipNerfModel.precision' not in keys


def test_bfloat16_weight_and_bias_gradients_are_float32_sums_not_rounded_to_bfloat16():
  gin.parse_config(TINY)
  rays = random_rays(2, 64)
  _, variables = mip_nerf.construct_model(random.PRNGKey(0), rays, False)
  loss = lambda name: lambda p: jnp.sum(_render(name, p, rays)['rgb'] ** 2)
  exact = jax.grad(loss('float32'))(variables['params'])
  low = jax.grad(loss('bfloat16'))(variables['params'])
  for layer, weight in itertools.product(('Dense_0', 'Dense_1', 'Dense_2', 'Dense_5'), ('kernel', 'bias')):
    grad, reference = (np.asarray(g['mlp'][layer][weight]) for g in (low, exact))
    assert grad.dtype == np.float32
    # Rounded to bfloat16 (8 significant bits) nearly every entry would be exactly a bfloat16 number.
    nonzero = grad[grad != 0]
    assert np.mean(nonzero == np.asarray(nonzero.astype(jnp.bfloat16).astype(np.float32))) < 0.5, (layer, weight)
    assert np.linalg.norm(grad - reference) < 0.05 * np.linalg.norm(reference), (layer, weight)
