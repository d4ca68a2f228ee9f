"""ReLU(x @ kernel + bias) in Pallas kernels that fuse the elementwise passes into the products (MLP.dense_kernel).

XLA runs a bfloat16 hidden layer as a matmul plus separate passes over its [N, 256] output: bias and ReLU going
forward; ReLU's gradient fused with the bias-gradient sum going back (a third of the step's kernel time in the
H100 profile, results/gpu). Here the forward kernel adds the bias and applies ReLU to the float32 accumulator
before its only store. Backward, both kernels mask the output gradient by y > 0 as they load it, so no masked
copy is ever written: one makes dx = (g * [y > 0]) @ kernel^T, the other the kernel's gradient x^T @ (g * [y > 0])
and the bias's, both accumulated and returned in float32 (partial sums over row splits, added after).
Each grid lists first the axis of the tiles that read the same rows: Triton launches the first axis fastest, so
those tiles run side by side and all but the first read the rows from L2, not memory.
The products run at the layer's matmul precision; unlike XLA's bfloat16 path the bias is added before the single
rounding to bfloat16, not after the product's. On an NVIDIA (or AMD) GPU Triton compiles the kernels; on any
other platform they run in Pallas's interpret mode (the tests, on the CPU). A step variant, timed by
bench.step_variants.
"""

import dataclasses
import functools

import gin
import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pallas_triton

from internal.models import activations


@gin.configurable('FusedDenseTiles')
@dataclasses.dataclass(frozen=True)
class Tiles:
  """Tile sizes (powers of two, >= 16) and launch settings of the fused kernels."""
  rows: int = 64  # Rows of a forward / dx tile: each tile reads a [K, block] weight block, so more rows re-read less.
  block: int = 128  # Output columns of a forward tile, inputs of a dx tile, each side of a weight-gradient tile.
  chunk: int = 64  # The depth of one product step of the forward and dx kernels' loops.
  # Rows of one step of the weight-gradient loop through a row split. Apart from rows: its three operands' steps
  # are what num_stages holds in shared memory (3 x 96 KB at 128 rows, over an H100's 227 KB).
  dw_rows: int = 64
  splits: int = 32  # Row splits of the weight gradient, each summing its own partial product.
  num_warps: int = 8
  num_stages: int = 3

  def __post_init__(self):
    for name in ('rows', 'block', 'chunk', 'dw_rows', 'num_warps'):
      value, least = getattr(self, name), 1 if name == 'num_warps' else 16  # Triton's products take 16 or more.
      if isinstance(value, bool) or not isinstance(value, int) or value < least or value & (value - 1):
        raise ValueError(f'FusedDenseTiles.{name} = {value!r}; expected a power of two >= {least}')
    for name in ('splits', 'num_stages'):
      value = getattr(self, name)
      if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f'FusedDenseTiles.{name} = {value!r}; expected an integer >= 1')


def dense_relu(x, kernel, bias, precision=None, tiles: Tiles = None):
  """relu(x [M, K] @ kernel [K, N] + bias [N]) [M, N] in x's dtype; gradients of kernel and bias in float32.
  tiles: None for Tiles() as gin binds them (FusedDenseTiles.*)."""
  tiles = tiles or Tiles()
  rows, depth, width = (_round_up(x.shape[0], max(tiles.rows, tiles.dw_rows) * tiles.splits),
                        _round_up(x.shape[1], max(tiles.block, tiles.chunk)), _round_up(kernel.shape[1], tiles.block))
  # Zero padding is inert: padded inputs and kernel rows add nothing, and the gradients of padded rows and
  # columns (relu(bias) > 0 there) are zero because the slice below passes them none.
  padded = _fused(_pad(x, rows, depth), _pad(kernel, depth, width), jnp.pad(bias, (0, width - bias.shape[0])),
                  precision, tiles)
  return padded[:x.shape[0], :kernel.shape[1]]


def _round_up(n: int, multiple: int) -> int:
  return -(-n // multiple) * multiple


def _pad(a, rows: int, cols: int):
  """a [r, c] padded with zeros to [rows, cols]."""
  return jnp.pad(a, ((0, rows - a.shape[0]), (0, cols - a.shape[1])))


@functools.partial(jax.custom_vjp, nondiff_argnums=(3, 4))
def _fused(x, kernel, bias, precision, tiles):
  """dense_relu on shapes that are whole tiles."""
  return _forward(x, kernel.astype(x.dtype), bias, precision, tiles)


def _fused_forward(x, kernel, bias, precision, tiles):
  low = kernel.astype(x.dtype)
  y = _forward(x, low, bias, precision, tiles)
  return y, (x, low, y)


def _fused_backward(precision, tiles, residuals, g):
  x, low, y = residuals
  dx = _input_gradient(g, y, low, precision, tiles)
  kernel_parts, bias_parts = _weight_gradients(x, g, y, precision, tiles)
  return dx, jnp.sum(kernel_parts, axis=0), jnp.sum(bias_parts, axis=0)


_fused.defvjp(_fused_forward, _fused_backward)


def _step_size(size: int, dtype) -> int:
  """A loop step of `size` 2-byte elements, kept to the same bytes for wider types (>= 16): Triton holds
  num_stages steps of every operand in shared memory, which float32 at the bfloat16 sizes would overflow."""
  return max(16, size * 2 // jnp.dtype(dtype).itemsize)


def _call(body, grid, in_specs, out_specs, out_shape, tiles: Tiles):
  """pallas_call of body over grid with the tiles' launch settings, its kernel named fused_dense_<body's name>:
  compiled by Triton for an NVIDIA or AMD GPU, interpreted for any other platform."""
  params = pallas_triton.CompilerParams(num_warps=tiles.num_warps, num_stages=tiles.num_stages)
  name = 'fused_dense_' + body.func.__name__.strip('_').removesuffix('_body')  # A profile's kernel name.
  kernel = lambda interpret: pl.pallas_call(body, out_shape=out_shape, grid=grid, in_specs=in_specs,
                                            out_specs=out_specs, interpret=interpret, compiler_params=params,
                                            name=name)
  # Chosen by the platform the step is lowered for, not the default backend: a GPU run's flop count lowers the
  # same step for the CPU (internal/run/flops.py), where only the interpreter runs.
  return lambda *args: jax.lax.platform_dependent(*args, cuda=kernel(False), rocm=kernel(False),
                                                  default=kernel(True))


def _product(a, b, contract, precision):
  """a @ b contracting dimension contract[0] of a with contract[1] of b, accumulated in float32."""
  return jax.lax.dot_general(a, b, (((contract[0],), (contract[1],)), ((), ())), precision=precision,
                             preferred_element_type=jnp.float32)


def _forward_body(x_ref, w_ref, b_ref, y_ref, *, chunk, precision):
  """One [rows, block] tile of relu(x @ w + b): the depth in chunks, bias and ReLU on the float32 sum."""
  def step(k, total):
    span = pl.ds(k * chunk, chunk)
    return total + _product(x_ref[:, span], w_ref[span, :], (1, 0), precision)
  total = jax.lax.fori_loop(0, x_ref.shape[1] // chunk, step, jnp.zeros(y_ref.shape, jnp.float32))
  y_ref[...] = jnp.maximum(total + b_ref[...].astype(jnp.float32)[None, :], 0).astype(y_ref.dtype)


def _forward(x, w, b, precision, tiles: Tiles):
  """relu(x [M, K] @ w [K, N] + b [N]) [M, N] in x's dtype."""
  (m, k), n = x.shape, w.shape[1]
  body = functools.partial(_forward_body, chunk=_step_size(tiles.chunk, x.dtype), precision=precision)
  return _call(body, (n // tiles.block, m // tiles.rows),
               [pl.BlockSpec((tiles.rows, k), lambda j, i: (i, 0)),
                pl.BlockSpec((k, tiles.block), lambda j, i: (0, j)),
                pl.BlockSpec((tiles.block,), lambda j, i: (j,))],
               pl.BlockSpec((tiles.rows, tiles.block), lambda j, i: (i, j)),
               jax.ShapeDtypeStruct((m, n), x.dtype), tiles)(x, w, b)


def _input_gradient_body(g_ref, y_ref, w_ref, dx_ref, *, chunk, precision):
  """One [rows, block] tile of dx = (g * [y > 0]) @ w^T, the outputs in chunks."""
  def step(n, total):
    span = pl.ds(n * chunk, chunk)
    masked = activations.gradient_from_output(y_ref[:, span], g_ref[:, span])
    return total + _product(masked, w_ref[:, span], (1, 1), precision)
  total = jax.lax.fori_loop(0, g_ref.shape[1] // chunk, step, jnp.zeros(dx_ref.shape, jnp.float32))
  dx_ref[...] = total.astype(dx_ref.dtype)


def _input_gradient(g, y, w, precision, tiles: Tiles):
  """dx [M, K] in g's dtype of output gradients g and outputs y [M, N], kernel w [K, N]."""
  (m, n), k = g.shape, w.shape[0]
  body = functools.partial(_input_gradient_body, chunk=_step_size(tiles.chunk, g.dtype), precision=precision)
  rows = pl.BlockSpec((tiles.rows, n), lambda j, i: (i, 0))
  return _call(body, (k // tiles.block, m // tiles.rows),
               [rows, rows, pl.BlockSpec((tiles.block, n), lambda j, i: (j, 0))],
               pl.BlockSpec((tiles.rows, tiles.block), lambda j, i: (i, j)),
               jax.ShapeDtypeStruct((m, k), g.dtype), tiles)(g, y, w)


def _weight_gradients_body(x_ref, g_ref, y_ref, dw_ref, db_ref, *, rows, precision):
  """One row split's [block, block] tile of x^T @ (g * [y > 0]) and its [block] of the bias gradient."""
  def step(r, totals):
    span = pl.ds(r * rows, rows)
    masked = activations.gradient_from_output(y_ref[span, :], g_ref[span, :])
    return (totals[0] + _product(x_ref[span, :], masked, (0, 0), precision),
            totals[1] + jnp.sum(masked.astype(jnp.float32), axis=0))
  weights, bias = jax.lax.fori_loop(0, x_ref.shape[0] // rows, step,
                                    (jnp.zeros(dw_ref.shape, jnp.float32), jnp.zeros(db_ref.shape, jnp.float32)))
  dw_ref[...] = weights

  @pl.when(pl.program_id(0) == 0)  # Every tile of a column block sums the same bias gradient; one stores it.
  def _():
    db_ref[...] = bias


def _weight_gradients(x, g, y, precision, tiles: Tiles):
  """Per row split: kernel gradients [splits, K, N] and bias gradients [splits, N] in float32."""
  (m, k), n, splits = x.shape, g.shape[1], tiles.splits
  per_split = m // splits
  body = functools.partial(_weight_gradients_body, rows=_step_size(tiles.dw_rows, x.dtype), precision=precision)
  columns = pl.BlockSpec((per_split, tiles.block), lambda i, j, s: (s, j))
  return _call(body, (k // tiles.block, n // tiles.block, splits),
               [pl.BlockSpec((per_split, tiles.block), lambda i, j, s: (s, i)), columns, columns],
               [pl.BlockSpec((None, tiles.block, tiles.block), lambda i, j, s: (s, i, j)),
                pl.BlockSpec((None, tiles.block), lambda i, j, s: (s, j))],
               [jax.ShapeDtypeStruct((splits, k, n), jnp.float32), jax.ShapeDtypeStruct((splits, n), jnp.float32)],
               tiles)(x, g, y)
