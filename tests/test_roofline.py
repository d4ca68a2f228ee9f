"""bench.roofline: the hand count of the step's matmuls against XLA's count of the traced step, and the floors."""

import json
import os
import subprocess
import sys

import jax
import pytest
from jax import random

from bench import common
from bench import roofline
from internal.datasets.batching import Batch
from internal.models import registry
from internal.training import flops
from internal.training import train_step as ts
from conftest import random_rays

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_a_layers_flops_and_bytes_by_hand():
  layer = roofline.Layer('x', rows=10, inputs=4, outputs=3, constant_inputs=1)
  # Forward 2*10*4*3, weight gradient the same, input gradient for the 3 inputs that have one: 2*10*3*3.
  assert layer.flops() == 240 + 240 + 180
  assert layer.min_bytes(2) == 2 * 10 * (4 + 3) * 3
  assert roofline.Layer('enc', 10, 4, 3, constant_inputs=4).min_bytes(2) == 2 * 10 * 7 * 2  # No input gradient.


def test_the_passes_the_fused_variants_leave_out_of_the_paper_step_by_hand():
  config = common.gin_config([roofline.PAPER_CONFIG], [], batch_size=64)
  saved = roofline.pass_savings(registry.build(config.model).mlp)
  # 8 trunk layers of 256, the encoding 99 wide, the skip layer's input 99 + 256 = 355, tiles 128 deep.
  skip = (355 + 384) + (384 + 256) + 2 * (384 - 355)  # Joined and padded; its dx sliced back; padding read twice.
  first = (99 + 128) + 2 * (128 - 99)
  assert saved['pallas_mask_at_store'] == 7 and saved['folded_bias'] == 8 and saved['folded_bias_cublaslt'] == 24
  assert saved['pallas_two_inputs'] == pytest.approx((skip + first) / 256 - 2)  # A second dW kernel: 2 passes.
  assert saved['pallas_fewer_passes'] == pytest.approx(7 + (skip + first) / 256 - 1)
  assert '| pallas_fewer_passes | 12.7 | 6.8 |' in roofline.savings_table(registry.build(config.model).mlp, 1 << 20)


def test_the_hand_count_is_xlas_count_of_the_traced_paper_step_within_its_element_wise_work():
  config = common.gin_config([roofline.PAPER_CONFIG], [], batch_size=64)
  rays = random_rays(0, 64)
  model, state = ts.create_train_state(config, random.PRNGKey(0), rays)
  batch = Batch(rays=rays, rgb=jax.numpy.zeros((64, 3)))
  xla = flops.lowered_flops(ts.make_train_step(config, model), state, batch, random.PRNGKey(1))
  hand = sum(layer.flops() for layer in roofline.step_layers(config, registry.build('mipnerf')))
  assert hand / 64 == pytest.approx(0.909e9, rel=1e-3)  # docs/benchmarks.md's roofline section.
  assert 1 < xla / hand < 1.02  # The encoding, sampling, rendering, losses and Adam add well under 2%.


def test_the_floor_is_the_slower_of_arithmetic_and_traffic_per_layer():
  wide = roofline.Layer('wide', rows=1000, inputs=1000, outputs=1000)  # 6 GFLOP, 12 MB in bfloat16.
  narrow = roofline.Layer('narrow', rows=10 ** 6, inputs=1, outputs=1)  # 6 MFLOP, 12 MB.
  result = roofline.floor([wide, narrow], 'bfloat16', tflops=1, tbytes_per_s=1)
  assert result['floor_ms'] == pytest.approx(6 + 0.012)  # wide by its flops, narrow by its bytes.
  assert result['compute_ms'] == pytest.approx(6.006) and result['memory_ms'] == pytest.approx(0.024)


def test_the_table_covers_every_gpu_and_precision_and_reads_measured_steps(tmp_path):
  measured = tmp_path / 'step_variants.json'
  measured.write_text(json.dumps({'device': 'NVIDIA H100 80GB HBM3', 'batch_size': 64, 'results': {
      'bfloat16': {'base': {'step_seconds': 0.02}, 'cublaslt': {'unavailable': 'no such option'}}}}))
  out = tmp_path / 'roofline.md'
  roofline.main(['--batch_size', '64', '--measured', str(measured), '--out', str(out)])
  rows = [line for line in out.read_text().splitlines() if line.startswith('| H')]
  assert len(rows) == len(roofline.GPUS) * len(roofline.ACTIVATION_BYTES)
  (row,) = [line for line in out.read_text().splitlines() if line.startswith('|') and 'step_variants' in line]
  cells = [c.strip() for c in row.split('|')[1:-1]]
  assert cells[1:5] == ['H100 SXM', 'bfloat16', 'base', '20.0']
  floor_ms = roofline.floor(roofline.step_layers(common.gin_config([roofline.PAPER_CONFIG], [], batch_size=64),
                                                 registry.build('mipnerf')), 'bfloat16', 989, 3.35)['floor_ms']
  assert float(cells[6]) == pytest.approx(floor_ms, abs=0.05)
  assert float(cells[7]) == pytest.approx(20 / floor_ms, abs=0.01)


def test_a_measured_file_from_another_device_is_named(tmp_path):
  cpu = tmp_path / 'cpu.json'
  cpu.write_text(json.dumps({'device': 'cpu', 'batch_size': 64, 'results': {}}))
  with pytest.raises(ValueError, match=f'--measured {cpu}: a cpu run; expected a paper-size run'):
    roofline.main(['--measured', str(cpu)])
  result = subprocess.run([sys.executable, '-m', 'bench.roofline', '--measured', str(cpu)], cwd=ROOT, text=True,
                          capture_output=True)
  assert result.returncode == 2 and result.stderr.startswith('error: --measured') and result.stderr.count('\n') == 1
