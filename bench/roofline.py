"""The step's floor on a GPU: each dense layer's matmul flops and the fewest bytes it must move, per precision.

Usage: python -m bench.roofline [--gin_configs FILE] [--batch_size 4096] [--measured JSON ...] [--out FILE]

A dense layer of R rows, K inputs and N outputs does 2RKN flops forward, 2RKN for its weight gradient and 2RKN
for its input's gradient (where the input depends on the parameters: not the encoding, not the view directions).
At the least it moves, in the activations' dtype, its input and output forward (R(K + N)), the output's gradient
and the input's gradient back (R(K + N), where the input needs one), and the input and the output's gradient for
the weight gradient (R(K + N)): bias, ReLU and their gradients fused into those products, nothing else kept.
Each layer's floor is the larger of flops / matmul rate and bytes / memory bandwidth; the step's floor is their
sum over layers and levels (everything outside the MLP taken as free). Rates are the datasheets' dense figures.
--measured reads step times from bench.device or bench.step_variants JSON files and sets each beside its GPU's
floor, with its matmul TFLOP/s by this hand count (which XLA's count of the traced step exceeds by under 1%).
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import dataclasses
import json
import os
import sys

from bench import common
from internal import cli
from internal.models import registry

PAPER_CONFIG = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                            'configs', 'freenerf', 'dtu3_freenerf.gin')
ACTIVATION_BYTES = {'float32': 4, 'default': 4, 'bfloat16': 2}
# Dense matmul TFLOP/s (float32 on CUDA cores, TF32 and bfloat16 on tensor cores) and HBM TB/s, from the
# datasheets of the SXM parts; the H200 is the H100's chip with faster memory.
GPUS = {'H100 SXM': {'float32': 67, 'default': 495, 'bfloat16': 989, 'hbm': 3.35},
        'H200': {'float32': 67, 'default': 495, 'bfloat16': 989, 'hbm': 4.8}}


@dataclasses.dataclass(frozen=True)
class Layer:
  """One dense layer evaluation: rows, inputs (of which those that need no gradient), outputs."""
  name: str
  rows: int
  inputs: int
  outputs: int
  constant_inputs: int = 0  # Inputs that do not depend on the parameters (encodings): no gradient.

  def flops(self) -> float:
    """Forward, weight-gradient and input-gradient matmul flops."""
    return 2. * self.rows * self.outputs * (3 * self.inputs - self.constant_inputs)

  def min_bytes(self, activation_bytes: int) -> float:
    """Fewest bytes: forward, weight gradient and (for inputs that need one) input gradient, each R(K + N)."""
    needs_input_grad = self.inputs > self.constant_inputs
    return activation_bytes * self.rows * (self.inputs + self.outputs) * (3 if needs_input_grad else 2)


def mip_nerf_layers(mlp, rays: int, samples: int):
  """Layers of one level of MLP over rays x samples Gaussians (the view term per ray, as the model computes it)."""
  shapes = {name: (i, o) for name, i, o in mlp.layer_shapes()}
  point_dim, view_dim = shapes['Dense_0'][0], shapes[f'Dense_{mlp.net_depth + 2}'][0] - mlp.net_width
  rows = rays * samples
  layers = [Layer('Dense_0', rows, point_dim, mlp.net_width, point_dim)]
  for i in range(1, mlp.net_depth + 1):
    inputs, outputs = shapes[f'Dense_{i}']
    layers.append(Layer(f'Dense_{i}', rows, inputs, outputs, inputs - mlp.net_width))
  heads = [name for name, _, _ in mlp.layer_shapes()[mlp.net_depth + 1:]]
  if mlp.use_viewdirs:
    bottleneck, view, *rest = heads
    layers.append(Layer(bottleneck, rows, *shapes[bottleneck]))
    layers.append(Layer(view + ' (per sample)', rows, mlp.net_width, mlp.net_width_viewdirs))
    layers.append(Layer(view + ' (per ray)', rays, view_dim, mlp.net_width_viewdirs, view_dim))
    heads = rest
  layers += [Layer(name, rows, *shapes[name]) for name in heads]
  return layers


def step_layers(config, model):
  """Every dense layer evaluation of one train step of config's mip-NeRF model, all levels."""
  return mip_nerf_layers(model.mlp, config.batch_size, model.num_samples) * model.num_levels


def floor(layers, precision: str, tflops: float, tbytes_per_s: float):
  """{'flops', 'bytes', 'compute_ms', 'memory_ms', 'floor_ms'} of layers at a precision and rates."""
  flops = sum(layer.flops() for layer in layers)
  size = ACTIVATION_BYTES[precision]
  per_layer = [max(layer.flops() / tflops, layer.min_bytes(size) / tbytes_per_s) / 1e9 for layer in layers]
  total_bytes = sum(layer.min_bytes(size) for layer in layers)
  return {'flops': flops, 'bytes': total_bytes, 'compute_ms': flops / tflops / 1e9,
          'memory_ms': total_bytes / tbytes_per_s / 1e9, 'floor_ms': sum(per_layer)}


def _copy_columns(depth: int, tile_depth: int) -> int:
  """Activation columns the fused layer's default moves to make a [R, depth] input whole tiles (read the parts,
  write the padded copy) and reads again as padding (forward and dx)."""
  padded = -(-depth // tile_depth) * tile_depth
  return depth + padded + 2 * (padded - depth)


def pass_savings(mlp, tile_depth: int = 128) -> dict:
  """{step variant: passes of a [R, net_width] activation it leaves out of a step, over R rows of every level}:
  the fused layers' counts of docs/benchmarks.md ('Fewer passes over the activations'), from the MLP's shapes."""
  width, trunk = mlp.net_width, mlp.net_depth
  shapes = {name: i for name, i, _ in mlp.layer_shapes()}
  first = shapes['Dense_0']
  skips = [shapes[f'Dense_{i + 1}'] for i in range(trunk - 1) if shapes[f'Dense_{i + 1}'] > width]
  # Skip layers: the joined input copied and padded, its padded dx sliced back to the ReLU's columns (read, write);
  # the first layer: the encoding padded. Reading the two parts in place costs a second weight-gradient kernel (the
  # output gradient and the output read again: 2 passes) on each skip layer.
  columns = sum(_copy_columns(k, tile_depth) + -(-k // tile_depth) * tile_depth + width for k in skips)
  two_inputs = (columns + _copy_columns(first, tile_depth)) / width - 2 * len(skips)
  mask_at_store = trunk - 1  # Each trunk layer whose output feeds the next: 8 -> 7 passes.
  return {'pallas_mask_at_store': mask_at_store, 'pallas_two_inputs': two_inputs,
          # Both, and the skip layers' second weight-gradient kernels load their output gradient masked already.
          'pallas_fewer_passes': mask_at_store + two_inputs + len(skips),
          'folded_bias': trunk,  # At most: the ReLU mask fused into the products, no bias pass (1 a trunk layer).
          'folded_bias_cublaslt': 3 * trunk}  # At most: 2 more a trunk layer with ReLU in the matmul's epilogue.


def savings_table(mlp, rows: int) -> str:
  """Markdown: per variant the passes saved a step and their bytes and milliseconds at each GPU's bandwidth."""
  pass_bytes = rows * mlp.net_width * ACTIVATION_BYTES['bfloat16']
  lines = ['| variant | passes saved a step | GB | ' + ' | '.join(f'{gpu} ms' for gpu in GPUS) + ' |',
           '|---' * (3 + len(GPUS)) + '|']
  for variant, passes in pass_savings(mlp).items():
    gb = passes * pass_bytes / 1e9
    lines.append(f'| {variant} | {passes:.1f} | {gb:.1f} | ' +
                 ' | '.join(f"{gb / rates['hbm']:.1f}" for rates in GPUS.values()) + ' |')
  return '\n'.join(lines)


def gpu_of(device_kind: str) -> str:
  """The GPUS key of a jax device_kind ('NVIDIA H200', 'NVIDIA H100 80GB HBM3'), or '' for another device."""
  return next((gpu for gpu in GPUS if gpu.split()[0] in device_kind), '')


def measured_steps(path: str):
  """[(GPU, precision, variant, seconds, batch size)] of a bench.device or bench.step_variants JSON."""
  with open(path) as f:
    report = json.load(f)
  gpu = gpu_of(report['device'])
  if not gpu or report.get('tiny'):
    raise ValueError(f'--measured {path}: a {report["device"]} run{" (tiny)" if report.get("tiny") else ""}; '
                     f'expected a paper-size run on one of {list(GPUS)}')
  steps = []
  for precision, result in report['results'].items():
    variants = result.get('methods', result)  # bench.device keys by method, bench.step_variants by variant.
    steps += [(gpu, precision, variant, figures['step_seconds'], report['batch_size'])
              for variant, figures in variants.items() if 'step_seconds' in figures]
  return steps


def table(layers, gpus) -> str:
  """Markdown: per GPU and precision the step's TFLOP, GB moved at the least, the rates, and the three floors in ms."""
  lines = ['| GPU | precision | TFLOP | GB at least | matmul TFLOP/s | HBM TB/s | matmuls at peak ms | '
           'bytes at bandwidth ms | floor ms |', '|---|---|---|---|---|---|---|---|---|']
  for gpu, rates in gpus.items():
    for precision in ACTIVATION_BYTES:
      f = floor(layers, precision, rates[precision], rates['hbm'])
      lines.append(f"| {gpu} | {precision} | {f['flops'] / 1e12:.2f} | {f['bytes'] / 1e9:.1f} | {rates[precision]} | "
                   f"{rates['hbm']} | {f['compute_ms']:.1f} | {f['memory_ms']:.1f} | {f['floor_ms']:.1f} |")
  return '\n'.join(lines)


def measured_table(layers_of, paths) -> str:
  """Markdown: each measured step beside its GPU's floor at its precision; layers_of(batch) gives the layers."""
  lines = ['| file | GPU | precision | method or variant | step ms | matmul TFLOP/s | floor ms | step / floor |',
           '|---|---|---|---|---|---|---|---|']
  for path in paths:
    for gpu, precision, variant, seconds, batch in measured_steps(path):
      layers = layers_of(batch)
      f = floor(layers, precision, GPUS[gpu][precision], GPUS[gpu]['hbm'])
      lines.append(f"| {os.path.relpath(path)} | {gpu} | {precision} | {variant} | {seconds * 1e3:.1f} | "
                   f"{f['flops'] / seconds / 1e12:.1f} | {f['floor_ms']:.1f} | {seconds * 1e3 / f['floor_ms']:.2f} |")
  return '\n'.join(lines)


def main(argv=None):
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--gin_configs', default=PAPER_CONFIG)
  parser.add_argument('--batch_size', type=int, default=4096)
  parser.add_argument('--measured', nargs='*', default=[], help='bench.device / bench.step_variants JSON files')
  parser.add_argument('--out', default='', help='also write the tables (markdown) here')
  args = parser.parse_args(argv)

  def model_of(batch_size):
    config = common.gin_config([args.gin_configs], [], batch_size=batch_size)
    return config, registry.build(config.model, white_background=config.white_background)

  def layers_of(batch_size):
    return step_layers(*model_of(batch_size))
  config, model = model_of(args.batch_size)
  layers = step_layers(config, model)
  command = cli.command_line('bench.roofline', argv)
  rows = config.batch_size * model.num_samples * model.num_levels
  text = (f'`{command}`\n\n{sum(l.flops() for l in layers) / args.batch_size / 1e9:.3f} GFLOP of matmuls a ray, '
          f'batch {args.batch_size}:\n\n' + table(layers, GPUS))
  text += (f'\n\nWhat the step variants that leave passes out should save (bfloat16; a pass is one read or write of '
           f'a [{rows:,}, {model.mlp.net_width}] activation, {rows * model.mlp.net_width * 2 / 1e9:.2f} GB; '
           'upper bounds where XLA must fuse what the variant allows):\n\n' + savings_table(model.mlp, rows))
  if args.measured:
    text += '\n\nMeasured steps against the floor:\n\n' + measured_table(layers_of, args.measured)
  print(text)
  if args.out:
    with open(args.out, 'w') as f:
      f.write(text + '\n')


if __name__ == '__main__':
  sys.exit(cli.run(main))
