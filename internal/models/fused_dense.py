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
other platform they run in Pallas's interpret mode (the tests, on the CPU; a run there is warned). A step variant,
timed by bench.step_variants.
Two settings leave out more passes over the activations (FusedDensePasses, each a step variant): mask_at_store,
where a layer's input is the previous layer's ReLU output, applies that ReLU's mask as the input gradient is
stored, so the previous layer loads its output gradient without loading its output to mask it; two_inputs reads
the skip layer's two inputs and the first layer's encoding as they are, the tail of their depth masked as it is
loaded, instead of concatenating and padding them to whole tiles.
"""

import dataclasses
import functools
import warnings

import gin
import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as pallas_triton

from internal.models import activations


@gin.configurable
@dataclasses.dataclass(frozen=True)
class FusedDenseTiles:
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


@gin.configurable
@dataclasses.dataclass(frozen=True)
class FusedDensePasses:
  """Passes over the activations the fused layer leaves out beyond its default (each a step variant)."""
  mask_at_store: bool = False  # The previous ReLU's mask applied as dx is stored: 8 -> 7 passes a hidden layer.
  two_inputs: bool = False  # Skip and first layers read without concatenated or padded copies: a masked tail.

  def __post_init__(self):
    for name in ('mask_at_store', 'two_inputs'):
      if not isinstance(getattr(self, name), bool):
        raise ValueError(f'FusedDensePasses.{name} = {getattr(self, name)!r}; expected True or False')


def warn_if_interpreted() -> None:
  """Warns in one line where the kernels would run interpreted: on any backend but an NVIDIA or AMD GPU."""
  backend = jax.default_backend()
  if backend != 'gpu':
    warnings.warn(f"MLP.dense_kernel = 'pallas' on a {backend}: Pallas interprets the fused kernels on any "
                  "platform but an NVIDIA or AMD GPU, and a step takes several times as long as with 'xla' "
                  '(docs/benchmarks.md)')


@dataclasses.dataclass(frozen=True)
class _Layout:
  """How the kernels read one fused layer: its tiles and matmul precision, the depth of each input part, how many
  leading columns of the first part are a ReLU's output whose mask dx takes as it is stored, and whether the
  output gradient arrives masked already (by the next layer's dx), so that y need not be loaded to mask it."""
  tiles: FusedDenseTiles
  precision: object
  depths: tuple
  relu_columns: int = 0
  gradient_masked: bool = False


def dense_relu(x, kernel, bias, precision=None, tiles: FusedDenseTiles = None, two_inputs: bool = False,
               mask_input_gradient: bool = False, gradient_masked: bool = False):
  """relu(x @ kernel [K, N] + bias [N]) [M, N] in x's dtype, x [M, K] or the parts of it (x_1 [M, K_1], ...);
  the gradients of kernel and bias in float32.

  tiles: None for FusedDenseTiles() as gin binds them. two_inputs: the parts read as they are (the
  tail of each one's depth masked), not concatenated and padded to whole tiles. mask_input_gradient: the first
  part is a ReLU's output, and its gradient is stored masked by x > 0, as that ReLU's own gradient would mask it
  (a gradient for nothing else). gradient_masked: the output gradient arrives masked by y > 0 (the next layer
  takes this layer's output with mask_input_gradient), so it is loaded without y.
  """
  tiles = tiles or FusedDenseTiles()
  parts = tuple(x) if isinstance(x, (tuple, list)) else (x,)
  depths = tuple(part.shape[1] for part in parts)
  rows, width = (_round_up(parts[0].shape[0], max(tiles.rows, tiles.dw_rows) * tiles.splits),
                 _round_up(kernel.shape[1], tiles.block))
  if two_inputs:
    starts = [sum(depths[:p]) for p in range(len(parts))]
    padded = tuple(_pad(part, rows, depth) for part, depth in zip(parts, depths))
    kernels = tuple(_pad(kernel[start:start + depth], depth, width) for start, depth in zip(starts, depths))
  else:  # Zero padding is inert: padded inputs and kernel rows add nothing to the products.
    joined = jnp.concatenate(parts, axis=-1) if len(parts) > 1 else parts[0]
    depth = _round_up(joined.shape[1], max(tiles.block, tiles.chunk))
    padded, kernels = (_pad(joined, rows, depth),), (_pad(kernel, depth, width),)
  layout = _Layout(tiles, precision, tuple(part.shape[1] for part in padded),
                   depths[0] if mask_input_gradient else 0, gradient_masked)
  # The gradients of padded rows and columns (relu(bias) > 0 there) are zero: the slice below passes them none.
  y = _fused(padded, kernels, jnp.pad(bias, (0, width - bias.shape[0])), layout)
  return y[:parts[0].shape[0], :kernel.shape[1]]


def _round_up(n: int, multiple: int) -> int:
  return -(-n // multiple) * multiple


def _pad(a, rows: int, cols: int):
  """a [r, c] padded with zeros to [rows, cols] (a itself where it has that shape)."""
  return a if a.shape == (rows, cols) else jnp.pad(a, ((0, rows - a.shape[0]), (0, cols - a.shape[1])))


@functools.partial(jax.custom_vjp, nondiff_argnums=(3,))
def _fused(parts, kernels, bias, layout):
  """dense_relu of parts [M, K_p] whose rows are whole tiles, kernels [K_p, N] whose columns are."""
  return _forward(parts, tuple(k.astype(parts[0].dtype) for k in kernels), bias, layout)


def _fused_forward(parts, kernels, bias, layout):
  lows = tuple(k.astype(parts[0].dtype) for k in kernels)
  y = _forward(parts, lows, bias, layout)
  return y, (parts, lows, None if layout.gradient_masked else y)


def _fused_backward(layout, residuals, g):
  parts, lows, y = residuals
  dxs = tuple(_input_gradient(g, y, low, part if p == 0 and layout.relu_columns else None, layout)
              for p, (part, low) in enumerate(zip(parts, lows)))
  sums = [_weight_gradients(part, g, y, low.shape[0], layout) for part, low in zip(parts, lows)]
  kernel_grads = tuple(jnp.sum(split, axis=0)[:low.shape[0]] for (split, _), low in zip(sums, lows))
  return dxs, kernel_grads, jnp.sum(sums[0][1], axis=0)  # Every part's kernel sums the same bias gradient.


_fused.defvjp(_fused_forward, _fused_backward)


def _step_size(size: int, dtype) -> int:
  """A loop step of `size` 2-byte elements, kept to the same bytes for wider types (>= 16): Triton holds
  num_stages steps of every operand in shared memory, which float32 at the bfloat16 sizes would overflow."""
  return max(16, size * 2 // jnp.dtype(dtype).itemsize)


def _call(body, grid, in_specs, out_specs, out_shape, tiles: FusedDenseTiles):
  """pallas_call of body over grid with the tiles' launch settings, its kernel named fused_dense_<body's name>:
  compiled by Triton for an NVIDIA or AMD GPU, interpreted for any other platform."""
  params = pallas_triton.CompilerParams(num_warps=tiles.num_warps, num_stages=tiles.num_stages)
  name = 'fused_dense_' + body.func.__name__.strip('_').removesuffix('_body')  # A profile's kernel name.
  kernel = lambda interpret: pl.pallas_call(body, out_shape=out_shape, grid=grid, in_specs=in_specs,
                                            out_specs=out_specs, interpret=interpret, compiler_params=params,
                                            name=name)
  # Chosen by the platform the step is lowered for, not the default backend: a GPU run's flop count lowers the
  # same step for the CPU (internal/training/flops.py), where only the interpreter runs.
  return lambda *args: jax.lax.platform_dependent(*args, cuda=kernel(False), rocm=kernel(False),
                                                  default=kernel(True))


def _product(a, b, contract, precision):
  """a @ b contracting dimension contract[0] of a with contract[1] of b, accumulated in float32."""
  return jax.lax.dot_general(a, b, (((contract[0],), (contract[1],)), ((), ())), precision=precision,
                             preferred_element_type=jnp.float32)


def _forward_body(*refs, depths, chunk, precision):
  """One [rows, block] tile of relu(sum_p x_p @ w_p + b): each depth in chunks, a ragged one's last chunk masked
  as it is loaded (read in place, no padded copy), bias and ReLU on the float32 sum. refs: x_p..., w_p..., b, y."""
  count = len(depths)
  b_ref, y_ref = refs[2 * count:]
  total = jnp.zeros(y_ref.shape, jnp.float32)
  for x_ref, w_ref, depth in zip(refs[:count], refs[count:2 * count], depths):
    def step(k, total, x_ref=x_ref, w_ref=w_ref, depth=depth):
      span = pl.ds(k * chunk, chunk)
      if depth % chunk == 0:
        return total + _product(x_ref[:, span], w_ref[span, :], (1, 0), precision)
      inside = k * chunk + jnp.arange(chunk) < depth
      x = pallas_triton.load(x_ref.at[:, span], mask=inside[None, :], other=0)
      w = pallas_triton.load(w_ref.at[span, :], mask=inside[:, None], other=0)
      return total + _product(x, w, (1, 0), precision)
    total = jax.lax.fori_loop(0, -(-depth // chunk), step, total)
  y_ref[...] = jnp.maximum(total + b_ref[...].astype(jnp.float32)[None, :], 0).astype(y_ref.dtype)


def _forward(parts, kernels, b, layout: _Layout):
  """relu(sum_p x_p [M, K_p] @ w_p [K_p, N] + b [N]) [M, N] in the parts' dtype."""
  tiles, m, n = layout.tiles, parts[0].shape[0], kernels[0].shape[1]
  body = functools.partial(_forward_body, depths=layout.depths, chunk=_step_size(tiles.chunk, parts[0].dtype),
                           precision=layout.precision)
  return _call(body, (n // tiles.block, m // tiles.rows),
               [pl.BlockSpec((tiles.rows, k), lambda j, i: (i, 0)) for k in layout.depths] +
               [pl.BlockSpec((k, tiles.block), lambda j, i: (0, j)) for k in layout.depths] +
               [pl.BlockSpec((tiles.block,), lambda j, i: (j,))],
               pl.BlockSpec((tiles.rows, tiles.block), lambda j, i: (i, j)),
               jax.ShapeDtypeStruct((m, n), parts[0].dtype), tiles)(*parts, *kernels, b)


def _output_gradient(g_ref, y_ref, rows, columns):
  """The output gradient's [rows, columns], masked by y > 0 as it is loaded (y_ref None: it came masked)."""
  g = g_ref[rows, columns]
  return g if y_ref is None else activations.gradient_from_output(y_ref[rows, columns], g)


def _input_gradient_body(*refs, chunk, precision, relu_columns, masked):
  """One [rows, block] tile of dx = (g * [y > 0]) @ w^T, the outputs in chunks; with relu_columns, the tile's
  columns before that masked by x > 0 as dx is stored. refs: g, y (unless masked), w, x (with relu_columns), dx."""
  g_ref, refs = refs[0], refs[1:]
  y_ref, refs = (None, refs) if masked else (refs[0], refs[1:])
  w_ref, x_ref, dx_ref = refs if relu_columns else (refs[0], None, refs[1])

  def step(n, total):
    span = pl.ds(n * chunk, chunk)
    return total + _product(_output_gradient(g_ref, y_ref, slice(None), span), w_ref[:, span], (1, 1), precision)
  total = jax.lax.fori_loop(0, g_ref.shape[1] // chunk, step, jnp.zeros(dx_ref.shape, jnp.float32))
  if relu_columns:
    columns = pl.program_id(0) * dx_ref.shape[1] + jnp.arange(dx_ref.shape[1])
    total = jnp.where((columns[None, :] >= relu_columns) | (x_ref[...] > 0), total, 0)
  dx_ref[...] = total.astype(dx_ref.dtype)


def _input_gradient(g, y, w, x, layout: _Layout):
  """dx [M, K] in g's dtype of output gradients g and outputs y [M, N] (None: g came masked), kernel w [K, N];
  x [M, K] (or None) the input whose first layout.relu_columns columns dx is stored masked by."""
  tiles, (m, n), k = layout.tiles, g.shape, w.shape[0]
  depth = _round_up(k, tiles.block)  # A ragged part's dx is made whole and cut: in training it is never used.
  body = functools.partial(_input_gradient_body, chunk=_step_size(tiles.chunk, g.dtype), precision=layout.precision,
                           relu_columns=layout.relu_columns if x is not None else 0, masked=y is None)
  rows = pl.BlockSpec((tiles.rows, n), lambda j, i: (i, 0))
  tile = pl.BlockSpec((tiles.rows, tiles.block), lambda j, i: (i, j))
  operands = [(g, rows)] + ([] if y is None else [(y, rows)]) + [
      (_pad(w, depth, n), pl.BlockSpec((tiles.block, n), lambda j, i: (j, 0)))] + ([] if x is None else [(x, tile)])
  dx = _call(body, (depth // tiles.block, m // tiles.rows), [spec for _, spec in operands], tile,
             jax.ShapeDtypeStruct((m, depth), g.dtype), tiles)(*(a for a, _ in operands))
  return dx[:, :k]


def _weight_gradients_body(*refs, rows, depth, precision, masked):
  """One row split's [block, block] tile of x^T @ (g * [y > 0]) and its [block] of the bias gradient; x's columns
  at depth and beyond read as zero. refs: x, g, y (unless masked), dw, db."""
  x_ref, g_ref, y_ref = (refs[0], refs[1], None) if masked else refs[:3]
  dw_ref, db_ref = refs[-2:]
  block = x_ref.shape[1]
  first = pl.program_id(0) * block

  def step(r, totals):
    span = pl.ds(r * rows, rows)
    masked_g = _output_gradient(g_ref, y_ref, span, slice(None))
    x = x_ref[span, :] if depth % block == 0 else pallas_triton.load(
        x_ref.at[span, :], mask=(first + jnp.arange(block) < depth)[None, :], other=0)
    return (totals[0] + _product(x, masked_g, (0, 0), precision),
            totals[1] + jnp.sum(masked_g.astype(jnp.float32), axis=0))
  weights, bias = jax.lax.fori_loop(0, x_ref.shape[0] // rows, step,
                                    (jnp.zeros(dw_ref.shape, jnp.float32), jnp.zeros(db_ref.shape, jnp.float32)))
  dw_ref[...] = weights

  @pl.when(pl.program_id(0) == 0)  # Every tile of a column block sums the same bias gradient; one stores it.
  def _():
    db_ref[...] = bias


def _weight_gradients(x, g, y, k: int, layout: _Layout):
  """Per row split: the kernel gradients [splits, K', N] (K' = k made whole tiles) of input x [M, k] and bias
  gradients [splits, N], in float32, of output gradients g and outputs y [M, N] (y None: g came masked)."""
  tiles, (m, n), splits = layout.tiles, g.shape, layout.tiles.splits
  per_split, depth = m // splits, _round_up(k, tiles.block)
  body = functools.partial(_weight_gradients_body, rows=_step_size(tiles.dw_rows, x.dtype), depth=k,
                           precision=layout.precision, masked=y is None)
  columns = pl.BlockSpec((per_split, tiles.block), lambda i, j, s: (s, j))
  return _call(body, (depth // tiles.block, n // tiles.block, splits),
               [pl.BlockSpec((per_split, tiles.block), lambda i, j, s: (s, i))] + [columns] * (1 if y is None else 2),
               [pl.BlockSpec((None, tiles.block, tiles.block), lambda i, j, s: (s, i, j)),
                pl.BlockSpec((None, tiles.block), lambda i, j, s: (s, j))],
               [jax.ShapeDtypeStruct((splits, depth, n), jnp.float32), jax.ShapeDtypeStruct((splits, n), jnp.float32)],
               tiles)(x, g, *([] if y is None else [y]))
