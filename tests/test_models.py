"""The MLP and the two-level model: defaults, noise modes, masks in the graph, normals on request."""

import gin
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import random

from conftest import random_rays
from internal import runs
from internal.models import encoding
from internal.models import freq_schedule
from internal.models import mip_nerf

TINY = ['MLP.net_depth = 2', 'MLP.net_width = 16', 'MLP.net_width_viewdirs = 8',
        'MipNerfModel.num_samples = 8']


def _tiny(bindings=()):
  gin.parse_config(TINY + list(bindings))
  return mip_nerf.construct_model(random.PRNGKey(0), random_rays(0, 4), white_background=False)


def test_default_parameter_count_and_layer_names():
  _, variables = mip_nerf.construct_model(random.PRNGKey(0), random_rays(0, 2), True)
  params = variables['params']['mlp']
  assert sum(x.size for x in jax.tree.leaves(params)) == 614276  # Scalars of the released MLP.
  assert sorted(params, key=lambda n: int(n.split('_')[1])) == [f'Dense_{i}' for i in range(12)]
  assert params['Dense_5']['kernel'].shape == (256 + 99, 256)  # Skip after trunk layer 4.
  assert params['Dense_10']['kernel'].shape == (256 + 27, 128)


def test_outputs_per_level_and_ranges():
  model, variables = _tiny()
  renderings, history = model.apply(variables, random.PRNGKey(1), random_rays(1, 5))
  assert len(renderings) == len(history) == 2
  for rendering, level in zip(renderings, history):
    assert rendering['rgb'].shape == (5, 3)
    assert level['rgb'].shape == (5, 8, 3) and level['density'].shape == (5, 8)
    assert level['t_vals'].shape == (5, 9)
    assert np.all(np.asarray(level['rgb']) >= -0.001) and np.all(np.asarray(level['rgb']) <= 1.001)
    assert 'normals' not in rendering


def _noise_shift(bindings):
  """Pre-activation density with noise minus without, at fixed Gaussians [2, 16]."""
  runs.bind_fresh([], TINY + bindings)
  mlp = mip_nerf.MLP()
  means = random.normal(random.PRNGKey(0), (2, 16, 3))
  covs = jnp.full((2, 16, 3), 1e-3)
  params = mlp.init(random.PRNGKey(1), None, means, covs, None, method=mip_nerf.MLP.predict_density)
  density = lambda key: mlp.apply(params, key, means, covs, None, method=mip_nerf.MLP.predict_density)
  raw = lambda d: np.log(np.expm1(np.asarray(d, np.float64)))  # Inverse softplus.
  return raw(density(random.PRNGKey(3))) - raw(density(None))


def test_density_noise_shared_by_default_as_released_and_per_sample_on_request():
  shared = _noise_shift(['MLP.density_noise = 1.0'])
  assert np.std(shared) < 1e-3 and abs(np.mean(shared)) > 1e-3  # One scalar for every sample.
  per_sample = _noise_shift(['MLP.density_noise = 1.0', 'MLP.density_noise_shared = False'])
  assert 0.6 < np.std(per_sample) < 1.4  # Independent N(0, 1) draws.


def test_no_mask_multiplication_in_graph_when_regularization_off():
  model, variables = _tiny()
  rays = random_rays(0, 4)
  masks = freq_schedule.encoding_masks(jnp.asarray(5), freq_reg=True, freq_reg_end=10,
                                   layout='released', max_vis_freq_ratio=0.,
                                   num_deg_point=16, num_deg_view=4)
  count = lambda *m: str(jax.make_jaxpr(lambda v: model.apply(v, None, rays, *m))(variables)).count(' mul ')
  # Point and view-direction masks, in each of the 2 levels.
  assert count(*masks) - count(None, None) == 4


def _shifted(encode, start):
  """encode with every feature from index start on shifted by 5."""
  return lambda *args, **kwargs: encode(*args, **kwargs).at[..., start:].add(5.)


def test_mask_zero_hides_encoding(monkeypatch):
  # A mask that keeps only the identity: changing the masked sin/cos features leaves every output unchanged.
  model, variables = _tiny()
  rays = random_rays(0, 4)
  masks = (freq_schedule.fixed_ratio_mask(99, 3 / 99), freq_schedule.fixed_ratio_mask(27, 3 / 27))
  render = lambda: [np.asarray(level['rgb']) for level in model.apply(variables, None, rays, *masks)[0]]
  before = render()
  ipe, pe = encoding.integrated_pos_enc, encoding.pos_enc
  monkeypatch.setattr(encoding, 'integrated_pos_enc', _shifted(ipe, 3))
  monkeypatch.setattr(encoding, 'pos_enc', _shifted(pe, 3))
  for level, expected in zip(render(), before):
    np.testing.assert_array_equal(level, expected)
  monkeypatch.setattr(encoding, 'integrated_pos_enc', _shifted(ipe, 0))  # The visible identity does matter.
  assert not np.allclose(render()[-1], before[-1])


def test_normals_only_when_asked_and_unit_length():
  model, variables = _tiny()
  renderings, _ = model.apply(variables, None, random_rays(4, 3), compute_normals=True,
                              compute_extras=True)
  normals = np.asarray(renderings[-1]['normals'])
  assert normals.shape == (3, 3) and np.all(np.isfinite(normals))
  assert np.all(np.linalg.norm(normals, axis=-1) <= 1 + 1e-5)


def test_normals_match_gradient_of_applied_density():
  model, variables = _tiny()
  mlp = mip_nerf.MLP()
  params = {'params': variables['params']['mlp']}
  means = random.normal(random.PRNGKey(5), (2, 4, 3))
  covs = jnp.full((2, 4, 3), 1e-4)
  normals = np.asarray(mlp.apply(params, means, covs, None, method=mip_nerf.MLP.normals))
  density = lambda m: mlp.apply(params, None, m, covs, None, method=mip_nerf.MLP.predict_density).sum()
  grad = np.asarray(jax.grad(density)(means))
  np.testing.assert_allclose(normals, -grad / np.linalg.norm(grad, axis=-1, keepdims=True), atol=1e-5)


def test_unknown_ray_shape_is_a_clear_error():
  with pytest.raises(ValueError, match='ray_shape'):
    _tiny(["MipNerfModel.ray_shape = 'sphere'"])


def _dense(layers, i, x):
  """Layer Dense_i of a parameter tree applied to x in true float32 (an accelerator's default would be TF32)."""
  return jnp.dot(x, layers[f'Dense_{i}']['kernel'], precision='highest') + layers[f'Dense_{i}']['bias']


def test_mlp_matches_concatenating_reference():
  # The split dense layers and the per-ray view term equal the textbook concatenated MLP.
  model, variables = _tiny()
  layers = variables['params']['mlp']
  rng = np.random.default_rng(0)
  means, covs = rng.normal(size=(2, 3, 8, 3)).astype(np.float32) * [[[[1.]]], [[[1e-2]]]]
  viewdirs = rng.normal(size=(3, 3)).astype(np.float32)
  rgb, density = mip_nerf.MLP().apply({'params': layers}, None, means, covs, viewdirs, None, None)
  x = encoding.integrated_pos_enc(means, covs, 0, 16)
  dense = lambda i, x: _dense(layers, i, x)
  x = jax.nn.relu(dense(1, jax.nn.relu(dense(0, x))))  # net_depth 2: no skip.
  np.testing.assert_allclose(density, jax.nn.softplus(dense(2, x)[..., 0] - 1.), rtol=1e-5, atol=1e-6)
  view = jnp.broadcast_to(encoding.pos_enc(viewdirs, 0, 4)[:, None], (3, 8, 27))
  x = jax.nn.relu(dense(4, jnp.concatenate([dense(3, x), view], axis=-1)))
  np.testing.assert_allclose(rgb, jax.nn.sigmoid(dense(5, x)) * 1.002 - 0.001, rtol=1e-5, atol=1e-6)


def test_skip_connection_reuses_masked_encoding():
  gin.parse_config(TINY + ['MLP.net_depth = 3', 'MLP.skip_layer = 1'])
  mlp = mip_nerf.MLP()
  means = np.random.default_rng(1).normal(size=(4, 3)).astype(np.float32)
  covs = np.full((4, 3), 1e-2, np.float32)
  params = mlp.init(random.PRNGKey(0), None, means, covs, None, method=mip_nerf.MLP.predict_density)
  layers = params['params']
  assert layers['Dense_2']['kernel'].shape == (16 + 99, 16)
  mask = freq_schedule.fixed_ratio_mask(99, 3 / 99)
  enc = encoding.integrated_pos_enc(means, covs, 0, 16) * mask
  dense = lambda i, x: _dense(layers, i, x)
  # skip_layer 1: the (masked) encoding is appended after layers 1 and 2.
  x = jax.nn.relu(dense(1, jax.nn.relu(dense(0, enc))))
  x = jax.nn.relu(dense(2, jnp.concatenate([x, enc], -1)))
  expected = jax.nn.softplus(dense(3, jnp.concatenate([x, enc], -1))[:, 0] - 1.)
  np.testing.assert_allclose(mlp.apply(params, None, means, covs, mask, method=mip_nerf.MLP.predict_density),
                             expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize('bindings, heads', [
    (['MLP.net_depth = 1', 'MLP.net_depth_viewdirs = 3'], 5),   # View branch deeper than the trunk + 1.
    (['MLP.net_depth = 3', 'MLP.net_depth_viewdirs = 1'], 3),
    (['MLP.use_viewdirs = False'], 1)])
def test_every_head_layer_is_created_and_used(bindings, heads):
  model, variables = _tiny(bindings)
  params = variables['params']['mlp']
  depth = gin.query_parameter('MLP.net_depth')
  # Trunk, density, then the heads: bottleneck, view layers and rgb (rgb only without view directions).
  assert sorted(params, key=lambda n: int(n.split('_')[1])) == [f'Dense_{i}' for i in range(depth + 1 + heads)]
  (renderings, _) = model.apply(variables, None, random_rays(1, 4))
  rgb = renderings[-1]['rgb']
  assert rgb.shape == (4, 3) and bool(jnp.all(jnp.isfinite(rgb)))


def test_model_and_released_equivalent_mlp_take_the_mlp_bindings_and_their_degrees():
  from bench import released_equivalent  # pylint: disable=import-outside-toplevel
  gin.parse_config(TINY + ['MLP.max_deg_point = 10', 'MLP.deg_view = 2'])
  model = mip_nerf.MipNerfModel()
  released = released_equivalent.ReleasedModel(num_samples=model.num_samples)  # Not gin-bound (bench-only).
  assert isinstance(released.mlp, released_equivalent.ReleasedMLP)
  assert model.mlp.encoding_degrees() == released.mlp.encoding_degrees() == (10, 2)
  assert released.mlp.layer_shapes() == model.mlp.layer_shapes()
  assert model.mlp.layer_shapes()[0] == ('Dense_0', encoding.width(10), 16) == ('Dense_0', 63, 16)
  rays = random_rays(0, 2)
  variables = mip_nerf.construct_model(random.PRNGKey(0), rays, False)[1]
  masks = (jnp.ones(63), jnp.ones(15))
  ours = model.apply(variables, None, rays, *masks)[0][-1]['rgb']
  with jax.default_matmul_precision('highest'):  # Ours is true float32; the released graph, the backend default.
    theirs = released.apply(variables, None, rays, *masks, mutable=['intermediates'])[0][0][-1]['rgb']
  np.testing.assert_allclose(theirs, ours, atol=1e-5)


def _rendered(kernel, precision, bindings=()):
  """Fine rgb, weight gradients and coarse normals of a model with 3 hidden layers, the skip into the third."""
  runs.bind_fresh([], TINY + ['MLP.net_depth = 3', 'MLP.skip_layer = 1', f"MLP.dense_kernel = '{kernel}'", *bindings])
  rays = random_rays(6, 8)
  model, variables = mip_nerf.construct_model(random.PRNGKey(0), rays, False, precision)
  render = lambda p: model.apply({'params': p}, None, rays, compute_normals=True)[0]
  renderings, pullback = jax.vjp(lambda p: [r['rgb'] for r in render(p)], variables['params'])
  return renderings[-1], pullback([jnp.ones_like(r) for r in renderings])[0], render(variables['params'])[0]


@pytest.mark.parametrize('precision, tolerance, bindings', [
    ('float32', 1e-5, ()), ('bfloat16', 3e-2, ()), ('float32', 1e-5, ('MLP.use_viewdirs = False',))])
def test_the_folded_bias_model_renders_trains_and_finds_normals_as_xla(precision, tolerance, bindings):
  rgb, grads, coarse = _rendered('folded_bias', precision, bindings)
  rgb_xla, grads_xla, coarse_xla = _rendered('xla', precision, bindings)
  relative = lambda a, b: np.linalg.norm(np.float64(a) - np.float64(b)) / np.linalg.norm(np.float64(b))
  assert relative(rgb, rgb_xla) < tolerance
  assert relative(coarse['normals'], coarse_xla['normals']) < tolerance
  for path, grad in jax.tree_util.tree_leaves_with_path(grads):
    reference = grads_xla
    for key in path:
      reference = reference[key.key]
    assert grad.dtype == jnp.float32 and relative(grad, reference) < tolerance, path
