"""Plain NeRF (Config.model = 'nerf'): encodings, masks, samples, forward pass against numpy, training on lego."""

import gin
import jax
import numpy as np
import pytest
from jax import random

from conftest import SHARED_DATA, random_rays
from test_checkpoints import ROOT
from test_datasets_core import encoded_dataset
from internal import config_loader
from internal.configs import Config
from internal.datasets import batching
from internal.datasets.batching import Batch
from internal.evaluation import evaluate
from internal.losses import occlusion
from internal.models import encoding
from internal.models import freq_schedule
from internal.models import mip_nerf
from internal.models import nerf
from internal.models import registry
from internal.pipeline import loop
from internal.training import train_step

TINY = ['NerfMLP.net_depth = 3', 'NerfMLP.net_width = 16', 'NerfMLP.net_width_viewdirs = 8',
        'NerfMLP.skip_layer = 1']


def _tiny_model(*bindings, num_rays=5):
  """(NerfModel, params) of a tiny NeRF initialized on random rays, white background."""
  gin.parse_config(TINY + list(bindings))
  model, variables = nerf.construct_model(random.PRNGKey(0), random_rays(0, num_rays), True)
  return model, variables['params']


# ---------------------------------------------------------------- encoding and masks

def test_interleaved_encoding_order_and_widths_by_hand():
  x = np.array([[0.3, -1.2, 2.0]], np.float32)
  expected = [*x[0]]
  for k in range(10):
    expected += [*np.sin(2.**k * x[0]), *np.cos(2.**k * x[0])]
  enc = np.asarray(encoding.interleaved_pos_enc(x, 10))
  assert enc.shape == (1, 3 + 3 * 2 * 10) == (1, 63)
  np.testing.assert_allclose(enc[0], expected, rtol=1e-5, atol=1e-5)
  assert encoding.interleaved_pos_enc(x, 4).shape == (1, 3 + 3 * 2 * 4) == (1, 27)


def test_interleaved_feature_layout_by_hand():
  kind, degree, coord = encoding.feature_layout(2, interleaved=True)
  assert kind.tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2, 1, 1, 1, 2, 2, 2]
  assert degree.tolist() == [-1, -1, -1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1]
  assert coord.tolist() == [0, 1, 2] * 5


def test_paper_mask_on_the_interleaved_layout_opens_sin_and_cos_of_a_band_together():
  # 10 degrees + identity = 11 groups; at t/T = 25/110, 11 t/T = 2.5: identity, degrees 0 and 1 open, degree 2 half.
  mask = np.asarray(freq_schedule.paper_mask(10, 25, 110, interleaved=True))
  assert mask.shape == (63,)
  np.testing.assert_array_equal(mask[:15], 1.)  # Identity 0..2, degree 0 3..8, degree 1 9..14.
  np.testing.assert_allclose(mask[15:21], 0.5)  # sin and cos of degree 2 alike.
  assert np.all(mask[21:] < 1e-7)
  config = Config(model='nerf', freq_reg=True, freq_reg_end=110, freq_mask_layout='paper')
  gin.parse_config(TINY)
  point, view = freq_schedule.model_masks(config, nerf.NerfModel(), 25)
  np.testing.assert_array_equal(point, mask)
  assert np.asarray(view).shape == (27,)
  # mip-NeRF keeps its block order: the same settings there give the block-order mask of width 99.
  mip_point, _ = freq_schedule.model_masks(config, mip_nerf.MipNerfModel(), 25)
  np.testing.assert_array_equal(mip_point, freq_schedule.paper_mask(16, 25, 110))


def _blender_code_mask(length, t, end):
  """The released Blender code's mask, in float64: ptr = length/3 t/T + 1; 3 int(ptr) ones, 3 at ptr - int(ptr)."""
  if t >= end:
    return np.ones(length)
  ptr = length / 3 * t / end + 1
  alpha = np.zeros(length)
  alpha[:3 * int(ptr)] = 1.
  alpha[3 * int(ptr):3 * int(ptr) + 3] = ptr - int(ptr)
  return np.clip(alpha, 1e-8, 1. - 1e-8)


def test_blender_freenerf_config_masks_every_step_as_the_released_blender_code():
  config = config_loader.load_config([str(ROOT / 'configs' / 'freenerf' / 'blender8_freenerf.gin')])
  end = config.freq_reg_end
  model = nerf.NerfModel()
  for t in (0, 1, 1190, 1191, 5000, 12345, 12500, 23809, 23810, end - 1, end, end + 1, config.max_steps):
    point, view = freq_schedule.model_masks(config, model, t)
    np.testing.assert_allclose(point, _blender_code_mask(63, t, end), atol=1e-6, err_msg=f'step {t}')
    np.testing.assert_allclose(view, _blender_code_mask(27, t, end), atol=1e-6, err_msg=f'step {t}')
  # Interleaved order: at t/T = 1/4 (ptr 6.25) sin of degree 2 (features 15..17) is open, its cos (18..20) at 1/4.
  point, _ = freq_schedule.model_masks(config, model, end // 4)
  np.testing.assert_array_equal(point[:18], 1.)
  np.testing.assert_allclose(point[18:21], .25, atol=1e-6)


# ---------------------------------------------------------------- initialization

def _xavier_bound(fan_in, fan_out, relu):
  return (2. if relu else 1.)**.5 * (6. / (fan_in + fan_out))**.5


def test_xavier_init_matches_the_released_blender_layers_statistics():
  gin.parse_config(['NerfMLP.weight_init = "xavier"'])
  mlp = nerf.NerfMLP()
  params = mlp.init(random.PRNGKey(3), None, np.zeros((2, 4, 3), np.float32), np.zeros((2, 3), np.float32),
                    None, None)['params']
  trunk = [f'Dense_{i}' for i in range(8)]
  relu_layers = set(trunk) | {'Dense_10'}  # The trunk and the view layer; density 8, feature 9, rgb 11 are linear.
  shapes = {'Dense_0': (63, 256), 'Dense_5': (319, 256), 'Dense_8': (256, 1), 'Dense_9': (256, 256),
            'Dense_10': (283, 128), 'Dense_11': (128, 3)}
  for name, layer in params.items():
    kernel, bias = np.asarray(layer['kernel']), np.asarray(layer['bias'])
    if name in shapes:
      assert kernel.shape == shapes[name]
    bound = _xavier_bound(*kernel.shape, name in relu_layers)
    np.testing.assert_array_equal(bias, 0.)
    assert np.abs(kernel).max() <= bound
    if kernel.size >= 10000:  # Uniform on [-b, b]: std b / sqrt(3), within 3% on >= 10^4 draws.
      assert abs(kernel.std() / (bound / 3**.5) - 1.) < .03, name


def test_default_init_stays_pytorch_linear_and_blender_configs_bind_xavier():
  params = nerf.NerfMLP().init(random.PRNGKey(3), None, np.zeros((2, 4, 3), np.float32),
                               np.zeros((2, 3), np.float32), None, None)['params']
  bias = np.asarray(params['Dense_1']['bias'])
  assert np.abs(bias).max() <= 1. / 16. and np.abs(bias).min() > 0.  # uniform(+-1/sqrt(256)), not zero.
  for name in ('nerf/blender8_nerf.gin', 'freenerf/blender8_freenerf.gin'):
    gin.clear_config()
    config_loader.load_config([str(ROOT / 'configs' / name)])
    assert nerf.NerfMLP().weight_init == 'xavier'


def test_unknown_weight_init_is_an_error_naming_the_setting():
  with pytest.raises(ValueError, match="NerfMLP.weight_init = 'he'; expected one of"):
    config_loader.load_config([], ["Config.model = 'nerf'", "NerfMLP.weight_init = 'he'"])


# ---------------------------------------------------------------- samples, occlusion loss

def test_fine_pass_is_the_sorted_union_of_64_coarse_and_128_importance_samples():
  model, params = _tiny_model()
  rays = random_rays(1, 6)
  _, history = model.apply({'params': params}, random.PRNGKey(3), rays)
  coarse, fine = (np.asarray(h['t_vals'])[:, :-1] for h in history)  # The last edge is far.
  assert coarse.shape == (6, 64) and fine.shape == (6, 192) and history[1]['density'].shape == (6, 192)
  assert np.all(np.diff(fine, axis=-1) >= 0) and np.all(np.diff(coarse, axis=-1) >= 0)
  for row_coarse, row_fine in zip(coarse, fine):
    assert np.all(np.isin(row_coarse, row_fine))
  assert np.all((fine >= 2.) & (fine <= 6.))


def test_occlusion_loss_sees_the_first_20_of_the_fine_passs_192_sorted_samples():
  model, params = _tiny_model()
  rays = random_rays(2, 4)
  config = Config(model='nerf', randomized=False, occ_reg_loss_mult=0.01, occ_reg_range=20, batch_size=4)
  batch = Batch(rays=rays, rgb=np.full((4, 3), 0.5, np.float32))
  _, stats = train_step.compute_loss(config, model, params, batch, random.PRNGKey(0), 1)
  _, history = model.apply({'params': params}, None, rays)
  density = np.asarray(history[1]['density'])
  assert density.shape == (4, 192)
  expected = density[:, :20].sum() / density.size  # Mean over all B x 192 entries of the masked density.
  np.testing.assert_allclose(stats['loss_occ'], expected, rtol=1e-5)
  direct = occlusion.occlusion_loss(density, np.asarray(history[1]['rgb']), 20, False, 15)
  np.testing.assert_allclose(direct, expected, rtol=1e-5)


# ---------------------------------------------------------------- the forward pass against numpy

def _np_encode(x, degrees):
  """[x, sin(2^0 x), cos(2^0 x), ...] in numpy."""
  parts = [x]
  for k in range(degrees):
    parts += [np.sin(2.**k * x), np.cos(2.**k * x)]
  return np.concatenate(parts, -1)


def _np_mlp(layers, points, viewdirs, depth, skip):
  """(rgb [B,S,3], density [B,S]) of NeRF's MLP from its parameters, numpy, input concatenated first at the skip."""
  dense = lambda i, x: x @ np.asarray(layers[f'Dense_{i}']['kernel']) + np.asarray(layers[f'Dense_{i}']['bias'])
  relu = lambda x: np.maximum(x, 0.)
  enc = _np_encode(points, 10)
  h = enc
  for i in range(depth):
    h = relu(dense(i, h))
    if i == skip:
      h = np.concatenate([enc, h], -1)
  density = relu(dense(depth, h)[..., 0])
  feature = dense(depth + 1, h)
  view = np.broadcast_to(_np_encode(viewdirs, 4)[:, None], feature.shape[:-1] + (27,))
  h = relu(dense(depth + 2, np.concatenate([feature, view], -1)))
  return 1. / (1. + np.exp(-dense(depth + 3, h))), density


def _np_render(rgb, density, z, directions):
  """NeRF's quadrature with a white background: (rgb [B,3], weights [B,S])."""
  dists = np.concatenate([np.diff(z, axis=-1), np.full(z[:, :1].shape, 1e10)], -1)
  alpha = 1. - np.exp(-density * dists * np.linalg.norm(directions, axis=-1, keepdims=True))
  transmittance = np.cumprod(np.concatenate([np.ones_like(alpha[:, :1]), 1. - alpha[:, :-1]], -1), -1)
  weights = alpha * transmittance
  return (weights[..., None] * rgb).sum(1) + (1. - weights.sum(-1, keepdims=True)), weights


def _np_importance(z, weights, n):
  """Deterministic hierarchical samples in NeRF's way: searchsorted on the cdf of the padded interior weights."""
  bins = 0.5 * (z[:, 1:] + z[:, :-1])
  w = weights[:, 1:-1] + 1e-5
  cdf = np.concatenate([np.zeros((len(z), 1)), np.cumsum(w / w.sum(-1, keepdims=True), -1)], -1)
  u = np.linspace(0., 1., n)
  out = []
  for c, b in zip(cdf, bins):
    above = np.minimum(np.searchsorted(c, u, side='right'), len(c) - 1)
    below = np.maximum(np.searchsorted(c, u, side='right') - 1, 0)
    denom = np.where(c[above] - c[below] < 1e-5, 1., c[above] - c[below])
    out.append(b[below] + (u - c[below]) / denom * (b[above] - b[below]))
  return np.stack(out)


def test_forward_pass_matches_an_independent_numpy_nerf():
  model, params = _tiny_model('NerfModel.num_coarse_samples = 16', 'NerfModel.num_fine_samples = 24')
  # A positive density bias so that the weights, and with them the importance samples, are far from uniform.
  params = jax.tree_util.tree_map_with_path(
      lambda path, x: x + 1.5 if 'Dense_3' in str(path) and 'bias' in str(path) else x, params)
  rays = random_rays(4, 5)
  renderings, history = model.apply({'params': params}, None, rays)
  origins, directions, viewdirs = (np.asarray(x, np.float64) for x in (rays.origins, rays.directions, rays.viewdirs))
  z = np.broadcast_to(np.linspace(2., 6., 16), (5, 16))
  outputs = []
  for level, mlp_name in enumerate(('coarse_mlp', 'fine_mlp')):
    points = origins[:, None] + directions[:, None] * z[..., None]
    rgb, density = _np_mlp(params[mlp_name], points, viewdirs, depth=3, skip=1)
    colour, weights = _np_render(rgb, density, z, directions)
    outputs.append((colour, weights, density))
    np.testing.assert_allclose(np.asarray(history[level]['t_vals'])[:, :-1], z, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(history[level]['density'], density, rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(renderings[level]['rgb'], colour, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(renderings[level]['weights'], weights, rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(renderings[level]['acc'], weights.sum(-1), rtol=1e-4, atol=1e-5)
    z = np.sort(np.concatenate([z, _np_importance(z, weights, 24)], -1), -1)
  assert np.ptp(outputs[0][1], axis=-1).min() > 1e-3  # Non-trivial weights: the check above has teeth.


# ---------------------------------------------------------------- batching, configuration, training

def test_central_crop_by_hand():
  crop = batching.central_crop(8, 6, 0.5)  # d = int(4 * 0.5) = 2 rows 2..5; int(3 * 0.5) = 1 column 2..3.
  rows, cols = np.divmod(crop, 6)
  assert sorted(set(rows.tolist())) == [2, 3, 4, 5] and sorted(set(cols.tolist())) == [2, 3] and crop.size == 8
  with pytest.raises(ValueError, match='precrop_frac'):
    batching.central_crop(8, 6, 0.1)


@pytest.mark.parametrize('mode', ['single_image', 'all_images'])
def test_batches_of_the_warm_up_steps_come_from_the_central_crop(mode):
  data = encoded_dataset(n=3, h=8, w=10)
  config = Config(batching=mode, batch_size=400, precrop_steps=3, precrop_frac=0.5)
  batcher = batching.make_batcher(data, config)
  for step in (1, 3):
    rows, cols = batcher(step).rays.origins[:, 1], batcher(step).rays.origins[:, 2]
    assert set(rows.tolist()) == {2., 3., 4., 5.} and set(cols.tolist()) == {3., 4., 5., 6.}
  assert len(set(batcher(4).rays.origins[:, 1].tolist())) == 8  # After the warm-up: every row.
  plain = batching.make_batcher(data, Config(batching=mode, batch_size=400))
  np.testing.assert_array_equal(plain(4).rgb, batcher(4).rgb)  # Same draws as without the crop.


def test_unknown_model_and_bad_crop_are_errors_naming_the_setting():
  with pytest.raises(ValueError, match="Config.model = 'nerff'"):
    config_loader.load_config([], ["Config.model = 'nerff'"])
  gin.clear_config()  # Parsing locks gin's config.
  with pytest.raises(ValueError, match='Config.precrop_frac'):
    config_loader.load_config([], ['Config.precrop_frac = 0.'])
  assert [name for name, _ in registry.gin_modules('nerf')] == ['NerfMLP', 'NerfModel']


def test_a_few_freenerf_on_nerf_steps_on_the_shared_lego(tmp_path):
  scene = SHARED_DATA / 'blender' / 'lego'
  if not scene.is_dir():
    pytest.skip(f'no shared Blender scene under {scene}')
  config = config_loader.load_config([str(ROOT / 'configs' / 'freenerf' / 'blender8_freenerf.gin')], TINY + [
      f"Config.data_dir = '{scene.parent}'", 'Config.factor = 16', 'Config.max_steps = 3', 'Config.batch_size = 64',
      'Config.precrop_steps = 2', 'Config.freq_reg_end = 2', f"Config.checkpoint_dir = '{tmp_path / 'run'}'",
      'NerfModel.num_coarse_samples = 8', 'NerfModel.num_fine_samples = 8', 'Config.train_render_every = 0',
      'Config.occ_reg_range = 4', 'Config.render_factor = 16', 'Config.eval_test_ids = [0]',
      'Config.compute_lpips = False'])
  result = loop.train(config)
  assert int(result.state.step) == 3 and result.signum is None
  assert (tmp_path / 'run' / 'checkpoints' / '3').is_dir()
  params = result.state.params
  assert set(params) == {'coarse_mlp', 'fine_mlp'} and params['fine_mlp']['Dense_0']['kernel'].shape == (63, 16)
  record = evaluate.evaluate(config)  # The checkpoint restores into NerfModel and renders a test view.
  assert [p['id'] for p in record['per_image']] == [0] and np.isfinite(record['means']['psnr'])
