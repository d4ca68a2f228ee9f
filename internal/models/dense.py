"""Dense layers as pure functions of their {'kernel', 'bias'} parameters: products at a matmul precision (lower
precisions cast the float32 kernel at use), the bias added in the released order, inputs given in parts that are
never concatenated, and the bias folded into the kernel as a row ('folded_bias'). Shared by every model."""

import jax
import jax.numpy as jnp

from internal.models import precision as precision_lib

FOLD_PAD = 8  # 'folded_bias' widens activations by a ones column and zeros, to keep their rows 16-byte aligned.


def glorot_layer(in_dim: int, out_dim: int):
  """Initializer of one dense layer's {'kernel' [in, out] (Glorot uniform), 'bias' [out] (zeros)}."""
  def init(key):
    return {'kernel': jax.nn.initializers.glorot_uniform()(key, (in_dim, out_dim)),
            'bias': jnp.zeros((out_dim,))}
  return init


def matmul(x, kernel, precision=None):
  """x [..., d] @ kernel [d, o] in x's dtype (the float32 kernel is cast at use) at a matmul precision."""
  if x.dtype == kernel.dtype:
    return jnp.matmul(x, kernel, precision=precision)
  return precision_lib.low_precision_matmul(x, kernel)


def add_bias(x, bias):
  """x [..., o] + bias [o] in x's dtype; at a lower precision than the bias's, its gradient summed in float32."""
  return x + bias if x.dtype == bias.dtype else precision_lib.add_low_precision_bias(x, bias)


def matmuls(kernel, *parts, precision=None):
  """[part @ its rows of kernel] of parts [..., d_i]: their concatenation @ kernel, the concatenation never made."""
  products, start = [], 0
  for part in parts:
    products.append(matmul(part, kernel[start:start + part.shape[-1]], precision))
    start += part.shape[-1]
  return products


def dense(layer, *parts, precision=None):
  """Dense layer {'kernel', 'bias'} of the concatenation of parts [..., d_i], never materialized."""
  products = matmuls(layer['kernel'], *parts, precision=precision)
  if parts[0].dtype == layer['bias'].dtype:  # The released order of the float32 sums: bias first.
    return sum(products, layer['bias'])
  return add_bias(sum(products[1:], products[0]), layer['bias'])


def with_ones(x):
  """x [N, K] widened to [N, K + FOLD_PAD]: a ones column, then zeros ('folded_bias' layers read the bias there)."""
  fill = jnp.zeros((x.shape[0], FOLD_PAD), x.dtype).at[:, 0].set(1)
  return jnp.concatenate([x, fill], axis=-1)


def folded_kernel(layer, width: int, ones_out: bool):
  """The kernel [K + FOLD_PAD, N (+ FOLD_PAD)] of a dense layer {'kernel' [K, N], 'bias' [N]} whose input's first
  part has `width` columns and then with_ones' columns: the bias is the row the ones column meets. With
  ones_out it passes that column on as its own output's (ReLU keeps 1), so the next layer can fold its bias too."""
  kernel, bias = layer['kernel'], layer['bias']
  columns = kernel.shape[1]
  folded = jnp.concatenate([kernel[:width], bias[None], jnp.zeros((FOLD_PAD - 1, columns)), kernel[width:]])
  if not ones_out:
    return folded
  return jnp.concatenate([folded, jnp.zeros((folded.shape[0], FOLD_PAD)).at[width, 0].set(1)], axis=1)


def sum_of(products):
  """The sum of a list of arrays, in their dtype."""
  return sum(products[1:], products[0])
