"""relu_from_output: jax's relu and its gradient, bit for bit, with the backward pass read from the output."""

import jax
import jax.numpy as jnp
import numpy as np
from jax import random

from conftest import assert_float32_exact, random_rays
from internal import runs
from internal.models import mip_nerf
from internal.models.activations import relu_from_output

TINY = ['MLP.net_depth = 3', 'MLP.net_width = 32', 'MLP.skip_layer = 2', 'MLP.net_width_viewdirs = 16',
        'MipNerfModel.num_samples = 8']


def test_values_and_gradients_equal_jax_relu_at_the_extremes():
  x = jnp.array([-3., -1e-45, -0., 0., 1e-45, 2., np.nan, np.inf, -np.inf, 3e38, -3e38], jnp.float32)
  weights = jnp.arange(1., 1. + x.size)
  for dtype in (jnp.float32, jnp.bfloat16):
    xs = x.astype(dtype)
    np.testing.assert_array_equal(*(np.float32(f(xs)) for f in (relu_from_output, jax.nn.relu)))
    grads = [jax.grad(lambda v, f=f: jnp.sum(f(v) * weights.astype(dtype)))(xs)
             for f in (relu_from_output, jax.nn.relu)]
    np.testing.assert_array_equal(*(np.float32(g) for g in grads))
    assert grads[0].dtype == dtype


def _weight_gradients(activation_binding):
  runs.bind_fresh([], TINY + [activation_binding])
  rays = random_rays(3, 32)
  model, variables = mip_nerf.construct_model(random.PRNGKey(0), rays, False)
  loss = lambda p: jnp.sum(model.apply({'params': p}, None, rays)[0][-1]['rgb'] ** 2)
  return jax.grad(loss)(variables['params'])


def test_the_models_gradients_are_unchanged_by_taking_relu_backward_from_the_output():
  reference = _weight_gradients('MLP.net_activation = @flax.nn.relu')
  ours = _weight_gradients('MLP.net_activation = @relu_from_output')
  for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(reference)):
    assert_float32_exact(a, b)
  assert any(np.any(np.asarray(g) != 0) for g in jax.tree.leaves(ours))
