"""The fused Pallas dense layer (MLP.dense_kernel = 'pallas'): relu(x @ W + b) and its gradients against float64
references and against XLA's layer, in interpret mode on the CPU, and its lowering to Triton for an NVIDIA GPU."""

import math
import re
import warnings

import gin
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import random
from jax._src.interpreters import mlir  # The Triton kernels' IR, read back below (no public API reads it).
from jax._src.lib import triton
from jax._src.lib.mlir import ir

from bench import step_variants
from conftest import random_rays
from internal import runs
from internal.models import fused_dense
from internal.training import flops
from internal.models import mip_nerf

SMALL = fused_dense.FusedDenseTiles(rows=16, block=32, chunk=16, splits=2, num_warps=4, num_stages=2)
HIGHEST = jax.lax.Precision.HIGHEST


def _inputs(seed, rows, depth, width, dtype=jnp.float32):
  """x [rows, depth], W [depth, width], b [width] (positive: padded rows would pass ReLU) and weights g."""
  keys = random.split(random.PRNGKey(seed), 4)
  return (random.normal(keys[0], (rows, depth)).astype(dtype),
          random.normal(keys[1], (depth, width)) / np.sqrt(depth),
          0.1 + jnp.abs(random.normal(keys[2], (width,))),
          random.normal(keys[3], (rows, width)))


def _reference(x, w, b, g):
  """(y, dx, dW, db) in float64 (numpy) of relu(x @ W + b), differentiated against sum(y * g)."""
  x, w, b, g = (np.asarray(a, np.float64) for a in (x, w, b, g))
  y = np.maximum(x @ w + b, 0)
  masked = g * (y > 0)
  return y, masked @ w.T, x.T @ masked, masked.sum(0)


def _fused(x, w, b, g, precision=HIGHEST, tiles=SMALL):
  """(y, dx, dW, db) of the fused layer (interpret mode)."""
  layer = lambda *a: fused_dense.dense_relu(*a, precision=precision, tiles=tiles)
  y, pullback = jax.vjp(layer, x, w, b)
  return (y,) + pullback(g.astype(y.dtype))


def _relative(a, b):
  a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
  return np.linalg.norm(a - b) / np.linalg.norm(b)


@pytest.mark.parametrize('shape', [(200, 99, 64), (64, 355, 96), (16, 32, 32)])  # Ragged and whole tiles.
def test_float32_values_and_gradients_equal_float64(shape):
  x, w, b, g = _inputs(0, *shape)
  fused, reference = _fused(x, w, b, g), _reference(x, w, b, g)
  for name, ours, exact in zip(('y', 'dx', 'dW', 'db'), fused, reference):
    assert ours.shape == exact.shape and ours.dtype == jnp.float32, name
    assert _relative(ours, exact) < 1e-6, name
  assert np.mean(reference[0] > 0) < 0.9  # ReLU clipped some outputs: the masks were exercised.


def test_bfloat16_matches_float64_on_its_inputs_and_keeps_float32_weight_gradients():
  x, w, b, g = _inputs(1, 200, 99, 64, jnp.bfloat16)
  g = g.astype(jnp.bfloat16)
  y, dx, dw, db = _fused(x, w, b, g, precision=None)
  # The reference sees the layer's own operands: the kernel rounded to bfloat16, the output's ReLU mask.
  exact = _reference(x, w.astype(jnp.bfloat16), b, g)
  assert (y.dtype, dx.dtype, dw.dtype, db.dtype) == (jnp.bfloat16, jnp.bfloat16, jnp.float32, jnp.float32)
  for name, ours, reference in zip(('y', 'dx', 'dW', 'db'), (y, dx, dw, db), exact):
    assert _relative(ours, reference) < 1e-2, name
  # Sums over 200 rows carry more than bfloat16's 8 bits: the float32 results are not rounded to it.
  assert np.any(np.asarray(dw) != np.asarray(dw.astype(jnp.bfloat16).astype(jnp.float32)))
  assert _relative(dw, exact[2]) < 1e-5 and _relative(db, exact[3]) < 1e-5


def _relu_parts(seed, rows=200, first=64, second=35, dtype=jnp.float32):
  """(parts, W, b, g): a ReLU's output [rows, first] (a third of it 0) and an encoding [rows, second] (ragged)."""
  x, w, b, g = _inputs(seed, rows, first + second, 64, dtype)
  return (jnp.maximum(x[:, :first], 0), x[:, first:]), w, b, g


@pytest.mark.parametrize('two_inputs', [False, True])
def test_two_parts_and_the_input_gradient_masked_as_stored_equal_float64(two_inputs):
  parts, w, b, g = _relu_parts(7)
  layer = lambda a, c, w, b: fused_dense.dense_relu((a, c), w, b, HIGHEST, SMALL, two_inputs=two_inputs,
                                                    mask_input_gradient=True)
  y, pullback = jax.vjp(layer, *parts, w, b)
  da, dc, dw, db = pullback(g)
  ry, rdx, rdw, rdb = _reference(jnp.concatenate(parts, axis=-1), w, b, g)
  relu_output = np.asarray(parts[0]) > 0
  # The first part's gradient is the ReLU's own: masked where its output is 0, the second part's as it is.
  for name, ours, exact in (('y', y, ry), ('dx relu part', da, rdx[:, :64] * relu_output),
                            ('dx encoding', dc, rdx[:, 64:]), ('dW', dw, rdw), ('db', db, rdb)):
    assert ours.shape == exact.shape, name
    assert _relative(ours, exact) < 1e-6, name
  assert np.any(rdx[:, :64][~relu_output] != 0)  # The mask changed something.


@pytest.mark.parametrize('dtype, tolerance', [(jnp.float32, 1e-6), (jnp.bfloat16, 1e-2)])
def test_a_chain_whose_output_gradient_arrives_masked_equals_float64(dtype, tolerance):
  """Layer 1 skips its mask (gradient_masked) because layer 2 stores its input gradient masked: the chain's
  gradients are those of relu(relu(x W1 + b1) W2 + b2)."""
  x, w1, b1, g = _inputs(8, 100, 48, 64, dtype)
  w2 = random.normal(random.PRNGKey(9), (64, 32)) / 8
  b2 = 0.1 * random.normal(random.PRNGKey(10), (32,))
  precision = HIGHEST if dtype == jnp.float32 else None

  def chain(x, w1, b1, w2, b2):
    hidden = fused_dense.dense_relu(x, w1, b1, precision, SMALL, gradient_masked=True)
    return fused_dense.dense_relu(hidden, w2, b2, precision, SMALL, mask_input_gradient=True)
  out, pullback = jax.vjp(chain, x, w1, b1, w2, b2)
  grads = pullback(g[:, :32].astype(out.dtype))

  def exact(x, w1, b1, w2, b2, g):
    x, w1, w2, g = (np.asarray(np.asarray(a, np.float32), np.float64) for a in (x, w1, w2, g))
    w1, w2 = (np.asarray(jnp.asarray(w, dtype).astype(jnp.float32), np.float64) for w in (w1, w2))
    hidden = np.maximum(x @ w1 + np.asarray(b1, np.float64), 0)
    if dtype == jnp.bfloat16:  # The layer's output is stored in bfloat16.
      hidden = np.asarray(jnp.asarray(hidden, jnp.float32).astype(dtype).astype(jnp.float32), np.float64)
    masked2 = g * (hidden @ w2 + np.asarray(b2, np.float64) > 0)
    masked1 = masked2 @ w2.T * (hidden > 0)
    return masked1 @ w1.T, x.T @ masked1, masked1.sum(0), hidden.T @ masked2, masked2.sum(0)
  for name, ours, reference in zip(('dx', 'dW1', 'db1', 'dW2', 'db2'), grads,
                                   exact(x, w1, b1, w2, b2, g[:, :32].astype(out.dtype))):
    assert _relative(ours, reference) < tolerance, name


def test_nonfinite_inputs_stay_in_their_rows_as_in_xla():
  x, w, b, g = _inputs(2, 48, 32, 32)
  x = x.at[3].set(jnp.nan).at[7, 0].set(jnp.inf)
  layer = lambda *a: jnp.maximum(jnp.matmul(a[0], a[1], precision=HIGHEST) + a[2], 0)
  y_xla, pullback = jax.vjp(layer, x, w, b)
  fused = _fused(x, w, b, g)
  np.testing.assert_array_equal(np.isnan(fused[0]), np.isnan(y_xla))
  dx_xla = pullback(g)[0]
  np.testing.assert_array_equal(np.isfinite(fused[1]), np.isfinite(dx_xla))
  finite = np.isfinite(y_xla).all(axis=1)
  np.testing.assert_allclose(fused[0][finite], y_xla[finite], rtol=1e-6, atol=1e-6)


def test_every_tile_setting_gives_the_same_layer():
  x, w, b, g = _inputs(3, 100, 70, 64)
  first = _fused(x, w, b, g)
  others = (fused_dense.FusedDenseTiles(rows=32, block=16, chunk=32, dw_rows=16, splits=3, num_warps=2, num_stages=1),
            fused_dense.FusedDenseTiles(rows=16, block=32, chunk=16, dw_rows=32, splits=2))  # Weight-gradient steps > rows.
  for tiles in others + (fused_dense.FusedDenseTiles(),):  # The defaults halve their loop steps for float32.
    for a, c in zip(first, _fused(x, w, b, g, tiles=tiles)):
      np.testing.assert_allclose(a, c, rtol=2e-5, atol=2e-6)


def _tiny_model(kernel, precision='float32', bindings=()):
  """(model, variables, rays) of the tiny model (4 hidden layers, the skip into the fourth) with MLP.dense_kernel."""
  runs.bind_fresh([], ['MLP.net_depth = 4', 'MLP.net_width = 32', 'MLP.skip_layer = 2', 'MLP.net_width_viewdirs = 16',
                       'MipNerfModel.num_samples = 8', f"MLP.dense_kernel = '{kernel}'",
                       'FusedDenseTiles.rows = 16', 'FusedDenseTiles.block = 32', 'FusedDenseTiles.chunk = 16',
                       'FusedDenseTiles.splits = 2', *bindings])
  rays = random_rays(4, 16)
  return mip_nerf.construct_model(random.PRNGKey(0), rays, False, precision) + (rays,)


def _model_outputs(kernel, precision='float32', bindings=()):
  """Fine rgb and weight gradients of the tiny model with MLP.dense_kernel = kernel."""
  model, variables, rays = _tiny_model(kernel, precision, bindings)
  render = lambda p: model.apply({'params': p}, None, rays)[0][-1]['rgb']
  rgb, pullback = jax.vjp(render, variables['params'])
  return rgb, pullback(jnp.ones_like(rgb))[0]


MASK_AT_STORE, TWO_INPUTS = 'FusedDensePasses.mask_at_store = True', 'FusedDensePasses.two_inputs = True'


@pytest.mark.parametrize('precision, tolerance, passes', [
    ('float32', 1e-5, ()), ('bfloat16', 3e-2, ()), ('float32', 1e-5, (MASK_AT_STORE,)),
    ('float32', 1e-5, (TWO_INPUTS,)), ('bfloat16', 3e-2, (MASK_AT_STORE, TWO_INPUTS))])
def test_the_model_renders_and_trains_as_with_xla(precision, tolerance, passes):
  rgb, grads = _model_outputs('pallas', precision, passes)
  rgb_xla, grads_xla = _model_outputs('xla', precision)
  assert _relative(rgb, rgb_xla) < tolerance
  for name in ('Dense_0', 'Dense_3', 'Dense_4'):  # First, skip (two parts) and the density head after them.
    for part in ('kernel', 'bias'):
      assert grads['mlp'][name][part].dtype == jnp.float32
      assert _relative(grads['mlp'][name][part], grads_xla['mlp'][name][part]) < tolerance, (name, part)


def test_the_passes_it_leaves_out_change_no_number_in_float32():
  rgb, grads = _model_outputs('pallas')
  for passes in ((MASK_AT_STORE,), (TWO_INPUTS,), (MASK_AT_STORE, TWO_INPUTS)):
    other_rgb, other_grads = _model_outputs('pallas', 'float32', passes)
    np.testing.assert_allclose(other_rgb, rgb, rtol=1e-6, atol=1e-7)
    for a, b in zip(jax.tree.leaves(other_grads), jax.tree.leaves(grads)):
      np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-7)


def test_on_a_cpu_the_fused_layer_warns_in_one_line_that_it_is_interpreted():
  with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter('always')
    _tiny_model('pallas')
  messages = {str(w.message) for w in caught if 'interprets' in str(w.message)}
  if jax.default_backend() == 'gpu':  # Compiled there: nothing to warn of.
    assert not messages
    return
  assert messages == {"MLP.dense_kernel = 'pallas' on a cpu: Pallas interprets the fused kernels on any platform "
                      "but an NVIDIA or AMD GPU, and a step takes several times as long as with 'xla' "
                      '(docs/benchmarks.md)'}


def test_unknown_kernel_and_non_relu_activation_are_named():
  with pytest.raises(ValueError, match=r"MLP.dense_kernel = 'triton'; expected one of \['xla', 'pallas', "
                                       r"'folded_bias'\]"):
    _model_outputs('triton')
  with pytest.raises(ValueError, match='MLP.net_activation is softplus, expected relu'):  # Checked as it loads.
    runs.bind_fresh([], ["MLP.dense_kernel = 'pallas'", 'MLP.net_activation = @flax.nn.softplus'])


def _for_an_h100():
  """A context in which jax lowers for CUDA without a GPU: jax >= 0.11 lowers Pallas's Triton kernels only for a GPU
  it recognises, here an abstract H100 (jax 0.10 assumed one)."""
  h100 = jax.sharding.AbstractDevice(device_kind='NVIDIA H100 80GB HBM3', num_cores=None, platform='gpu')
  mesh = jax.sharding.AbstractMesh((1,), ('batch',), (jax.sharding.AxisType.Auto,), abstract_device=h100)
  return jax.sharding.use_abstract_mesh(mesh)


def test_the_platform_lowered_for_picks_triton_or_the_interpreter():
  """A GPU run's flop count lowers its step for the CPU (internal/training/flops.py): the kernel must follow the
  platform lowered for, not the process's backend."""
  model, variables, rays = _tiny_model('pallas', 'bfloat16')
  loss = jax.jit(jax.grad(lambda p: jnp.sum(model.apply({'params': p}, None, rays)[0][-1]['rgb'])))
  with _for_an_h100():
    traced = loss.trace(variables['params'])
    on_gpu, on_cpu = (traced.lower(lowering_platforms=(p,)).as_text() for p in ('cuda', 'cpu'))
  assert set(re.findall(r'name = "(fused_dense_\w+)"', on_gpu)) == {
      'fused_dense_forward', 'fused_dense_input_gradient', 'fused_dense_weight_gradients'}
  assert 'triton' not in on_cpu and 'fused_dense' not in on_cpu and 'while' in on_cpu
  assert flops.lowered_flops(loss, variables['params']) > 0


def _lowered_for_an_h100(rows, depth, dtype, precision=None, tiles=None, passes=fused_dense.FusedDensePasses()):
  """The gradient of the fused layer [rows, depth] -> [rows, 256] in dtype, lowered for CUDA (an abstract H100);
  past 256 inputs as the skip layer's two parts (the first a ReLU's output) with passes' settings."""
  def loss(w, b, g, *parts):
    y = fused_dense.dense_relu(parts, w, b, precision, tiles, passes.two_inputs, passes.mask_at_store,
                               passes.mask_at_store)
    return jnp.sum(y.astype(jnp.float32) * g)
  depths = (256, depth - 256) if depth > 256 else (depth,)
  shapes = [((depth, 256), jnp.float32), ((256,), jnp.float32), ((rows, 256), jnp.float32)] + [
      ((rows, d), dtype) for d in depths]
  with _for_an_h100():
    traced = jax.jit(jax.grad(loss, argnums=(0, 1, 3, 4)[:2 + len(depths)])).trace(
        *(jax.ShapeDtypeStruct(*s) for s in shapes))
    return traced.lower(lowering_platforms=('cuda',))


@pytest.mark.parametrize('depth', [99, 256, 355])  # The paper's first, hidden and skip layers.
def test_the_paper_layer_lowers_to_three_triton_kernels_for_an_nvidia_gpu(depth):
  text = _lowered_for_an_h100(524288, depth, jnp.bfloat16).as_text()
  assert text.count('__gpu$xla.gpu.triton') == 3
  assert sorted(re.findall(r'name = "(fused_dense_\w+)"', text)) == [
      'fused_dense_forward', 'fused_dense_input_gradient', 'fused_dense_weight_gradients']


@pytest.mark.parametrize('mask_at_store', [False, True])
@pytest.mark.parametrize('two_inputs', [False, True])
def test_the_passes_left_out_are_out_of_the_lowered_program(mask_at_store, two_inputs):
  lowered = _lowered_for_an_h100(8192, 355, jnp.bfloat16, passes=fused_dense.FusedDensePasses(mask_at_store, two_inputs))
  # Copies of the activations: the skip layer's inputs concatenated and padded, its input gradient sliced.
  copies = re.findall(r'stablehlo\.(?:concatenate|pad)\b[^\n]*tensor<8192x\d+xbf16>', lowered.as_text())
  assert bool(copies) != two_inputs, copies
  kernels = _loop_loads(lowered)
  names = [name for name, _, _ in kernels]  # dx and dW kernels for each input part (the forward's y: for masks).
  for kernel in ('fused_dense_input_gradient', 'fused_dense_weight_gradients'):
    assert names.count(kernel) == 1 + two_inputs
  assert names.count('fused_dense_forward') == (not mask_at_store)
  for name, _, loops in kernels:  # Masked as stored, the gradient is loaded without the output to mask it.
    loads = len(loops[0])
    assert loads == {'fused_dense_forward': 2, 'fused_dense_input_gradient': 3 - mask_at_store,
                     'fused_dense_weight_gradients': 3 - mask_at_store}[name], (name, loops)


def _operations(operation):
  """Every operation nested in an MLIR operation, depth first."""
  for region in operation.regions:
    for block in region.blocks:
      for inner in block.operations:
        yield inner.operation
        yield from _operations(inner.operation)


def _loop_loads(lowered):
  """[(kernel name, num_stages, [[(shape, dtype) of each load inside a loop] for each loop])] of the Triton kernels
  of a lowered program: the loads Triton's pipeliner keeps num_stages copies of in shared memory, a loop at a
  time."""
  context = mlir.JaxIrContext()
  context.append_dialect_registry(mlir.upstream_dialects)
  triton.dialect.register_dialect(context)
  context.load_all_available_dialects()
  kernels = []
  for call in _operations(lowered.compiler_ir('stablehlo').operation):
    if call.name == 'stablehlo.custom_call' and 'gpu.triton' in str(call.attributes['call_target_name']):
      config = call.attributes['mhlo.backend_config']
      with context:
        module = ir.Module.parse(ir.StringAttr(config['ir']).value_bytes)
        loops = [[str(load.results[0].type) for load in _operations(loop) if load.name == 'tt.load']
                 for loop in _operations(module.operation) if loop.name == 'scf.for']
      kernels.append((
          ir.StringAttr(config['name']).value, ir.IntegerAttr(config['num_stages']).value,
          [[(tuple(int(n) for n in shape.split('x')), dtype)
            for shape, dtype in (re.fullmatch(r'tensor<([\dx]+)x(\w+)>', load).groups() for load in loads)]
           for loads in loops]))
  return kernels


H100_SHARED_MEMORY = 227 * 1024  # Bytes a block may use (Triton's limit for sm_90).


@pytest.mark.parametrize('variant', [v for v, (bindings, _) in step_variants.VARIANTS.items()
                                     if step_variants.PALLAS[0] in bindings])
def test_each_tiling_fits_an_h100s_shared_memory_float32_taking_half_steps(variant):
  gin.parse_config(step_variants.VARIANTS[variant][0])
  tiles, passes = fused_dense.FusedDenseTiles(), fused_dense.FusedDensePasses()
  sizes = {'bf16': 2, 'f32': 4}
  stages = {}
  for dtype, precision in ((jnp.bfloat16, None), (jnp.float32, HIGHEST)):
    kernels = _loop_loads(_lowered_for_an_h100(8192, 355, dtype, precision, tiles, passes))
    stages[dtype] = [(name, sorted(math.prod(shape) for loads in loops for shape, _ in loads))
                     for name, _, loops in kernels]
    for name, num_stages, loops in kernels:
      assert num_stages == tiles.num_stages and all(loops), name
      pipelined = num_stages * max(sum(math.prod(shape) * sizes[element] for shape, element in loads)
                                   for loads in loops)
      assert pipelined <= H100_SHARED_MEMORY, (variant, name, dtype.dtype.name, pipelined)
      if name == 'fused_dense_weight_gradients':  # Its loop steps through dw_rows rows, half that in float32.
        step = tiles.dw_rows // (2 if dtype == jnp.float32 else 1)
        assert {shape for loads in loops for shape, _ in loads} == {(step, tiles.block)}
  # float32 steps through half the rows (weight gradient) or depth (forward, dx) of bfloat16's, in the same bytes.
  assert [(name, [2 * n for n in elements]) for name, elements in stages[jnp.float32]] == stages[jnp.bfloat16]


def test_a_profile_counts_the_fused_kernels_apart_from_xlas_matmuls_and_fusions():
  from bench import kernel_profile  # pylint: disable=import-outside-toplevel
  expected = {'fused_dense_forward': 'fused dense (Pallas)', 'fused_dense_weight_gradients': 'fused dense (Pallas)',
              'gemm_fusion_dot_60': 'matmul', 'nvjet_sm90_tst_128x160_64x5_2x1_v_bz_TNT': 'matmul',
              'input_reduce_select_fusion_1': 'reduction', 'loop_add_fusion_3': 'element-wise fusion'}
  assert {name: kernel_profile.kernel_kind(name, 'command_buffer_1') for name in expected} == expected


@pytest.mark.skipif(jax.default_backend() != 'gpu', reason='the compiled Triton kernels need an NVIDIA GPU')
@pytest.mark.parametrize('variant', ['pallas', 'pallas_rows256', 'pallas_fewer_passes'])
@pytest.mark.parametrize('dtype, precision, tolerance', [(jnp.bfloat16, None, 1e-2), (jnp.float32, HIGHEST, 1e-5)])
def test_on_a_gpu_the_compiled_kernels_equal_float64(variant, dtype, precision, tolerance):
  gin.parse_config(step_variants.VARIANTS[variant][0])
  tiles, passes = fused_dense.FusedDenseTiles(), fused_dense.FusedDensePasses()
  x, w, b, g = _inputs(5, 8192 + 100, 355, 256, dtype)  # The skip layer: a ReLU's output and the encoding.
  x = x.at[:, :256].set(jnp.maximum(x[:, :256], 0))
  layer = lambda a, c, w, b: fused_dense.dense_relu((a, c), w, b, precision, tiles, passes.two_inputs,
                                                    passes.mask_at_store)
  y, pullback = jax.jit(lambda *a: jax.vjp(layer, *a))(x[:, :256], x[:, 256:], w, b)
  da, dc, dw, db = jax.jit(pullback)(g.astype(dtype))
  exact = _reference(x, w.astype(dtype), b, g.astype(dtype))
  masked_da = exact[1][:, :256] * (np.asarray(x[:, :256], np.float32) > 0) if passes.mask_at_store else \
      exact[1][:, :256]
  for name, ours, reference in (('y', y, exact[0]), ('dx relu part', da, masked_da),
                                ('dx encoding', dc, exact[1][:, 256:]), ('dW', dw, exact[2]), ('db', db, exact[3])):
    assert np.all(np.isfinite(np.asarray(ours, np.float32))), name
    assert _relative(ours, reference) < tolerance, name
