"""internal/models/dense.py: dense layers of parts never concatenated, and the bias folded into the kernel."""

import jax
import jax.numpy as jnp
import numpy as np
from jax import random

from internal.models import dense


def test_a_layer_of_parts_equals_the_layer_of_their_concatenation_in_float64():
  rng = np.random.default_rng(0)
  parts = [rng.normal(size=(20, d)).astype(np.float32) for d in (5, 3, 9)]
  layer = {'kernel': jnp.asarray(rng.normal(size=(17, 4)), jnp.float32),
           'bias': jnp.asarray(rng.normal(size=4), jnp.float32)}
  ours = dense.dense(layer, *map(jnp.asarray, parts), precision='highest')
  x = np.concatenate(parts, axis=-1).astype(np.float64)
  expected = x @ np.asarray(layer['kernel'], np.float64) + np.asarray(layer['bias'], np.float64)
  np.testing.assert_allclose(ours, expected, rtol=1e-5, atol=1e-5)


def test_bfloat16_inputs_keep_their_dtype_and_the_bias_gradient_is_summed_in_float32():
  x = jnp.ones((4097, 3), jnp.bfloat16)
  layer = {'kernel': jnp.full((3, 2), 0.5), 'bias': jnp.zeros(2)}
  assert dense.dense(layer, x).dtype == jnp.bfloat16
  grad = jax.grad(lambda l: dense.dense(l, x).astype(jnp.float32).sum())(layer)
  assert grad['bias'].dtype == jnp.float32 and float(grad['bias'][0]) == 4097.  # bfloat16 holds 4096 or 4112, not 4097.


def test_glorot_layer_draws_a_kernel_within_its_bound_and_a_zero_bias():
  params = dense.glorot_layer(30, 10)(random.PRNGKey(0))
  bound = np.sqrt(6. / (30 + 10))
  assert params['kernel'].shape == (30, 10) and float(jnp.abs(params['kernel']).max()) <= bound
  assert float(jnp.abs(params['kernel']).max()) > 0.9 * bound and not params['bias'].any()


def test_a_bias_folded_into_its_kernel_as_a_row_equals_float64_and_passes_the_ones_column_on():
  rng = np.random.default_rng(3)
  hidden, enc, g = (rng.normal(size=s).astype(np.float32) for s in ((50, 16), (50, 7), (50, 12)))
  layer = {'kernel': jnp.asarray(rng.normal(size=(23, 12)), jnp.float32),
           'bias': jnp.asarray(rng.normal(size=12), jnp.float32)}

  def folded(layer, hidden, enc):  # The skip layer's form: the ones column after the hidden part, then enc.
    kernel = dense.folded_kernel(layer, 16, ones_out=True)
    return jax.nn.relu(sum(dense.matmuls(kernel, dense.with_ones(hidden), enc, precision='highest')))
  out, pullback = jax.vjp(folded, layer, jnp.asarray(hidden), jnp.asarray(enc))
  grads, dhidden, _ = pullback(jnp.concatenate([g, jnp.full((50, dense.FOLD_PAD), 5.)], axis=-1))
  x = np.concatenate([hidden, enc], axis=-1).astype(np.float64)
  kernel, bias = (np.asarray(layer[k], np.float64) for k in ('kernel', 'bias'))
  pre = x @ kernel + bias
  masked = g * (pre > 0)
  assert out.shape == (50, 12 + dense.FOLD_PAD)
  np.testing.assert_allclose(out[:, :12], np.maximum(pre, 0), rtol=1e-6, atol=1e-6)
  np.testing.assert_array_equal(out[:, 12:], np.tile([1.] + [0.] * (dense.FOLD_PAD - 1), (50, 1)))
  np.testing.assert_allclose(grads['kernel'], x.T @ masked, rtol=1e-6, atol=1e-5)
  np.testing.assert_allclose(grads['bias'], masked.sum(0), rtol=1e-6, atol=1e-5)  # The kernel's ones row.
  np.testing.assert_allclose(dhidden, (masked @ kernel.T)[:, :16], rtol=1e-6, atol=1e-5)
