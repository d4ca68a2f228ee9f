"""bench.device on CPU at a tiny size: every figure is written, consistent with the others, for each precision."""

import json
import os

import jax
import pytest

from bench import device
from internal import cli

ARGS = ['--tiny', '--batch_size', '64', '--repeats', '1', '--render_rays', '64', '--methods', 'freenerf',
        '--precisions', 'bfloat16']


def test_device_benchmark_writes_every_figure(tmp_path):
  out = str(tmp_path / 'results.json')
  device.main(ARGS + ['--out', out])
  with open(out) as f:
    report = json.load(f)
  assert report['device'] == jax.devices()[0].device_kind and report['jax_version'] == jax.__version__
  recorded = os.path.relpath(out, cli.REPOSITORY)  # Its path relative to the repository.
  assert report['command'] == 'python -m bench.device ' + ' '.join(ARGS + ['--out', recorded])
  assert list(report['results']) == ['bfloat16']
  for result in report['results'].values():
    # The MLP's [B, W] @ [W, W] and [B * S, W] @ [W, W] (2 x 32 MLP, 8 samples), and a side-64 square.
    assert result['matmul_shapes'] == [[64, 32, 32], [512, 32, 32], [64, 64, 64]]
    assert result['peak_memory_bytes'] > 0 and result['memory_source'].split()[0] in ('device', 'host')
    figures = result['methods']['freenerf']
    assert figures['rays_per_s'] == pytest.approx(64 / figures['step_seconds'])
    assert figures['achieved_tflops'] == pytest.approx(figures['step_tflop'] / figures['step_seconds'])
    assert figures['fraction_of_peak'] == pytest.approx(figures['achieved_tflops'] / result['matmul_peak_tflops'])
    assert figures['step_tflop'] > 0 and figures['xla_step_bytes'] > 0 and figures['render_rays_per_s'] > 0


def test_methods_follow_the_gin_configs_present_and_bad_names_are_named():
  expected = [m for m in ('mipnerf', 'freenerf', 'regnerf')
              if os.path.isfile(os.path.join(device.ROOT, device.METHOD_CONFIGS[m]))]
  assert device.available_methods() == expected and expected[:2] == ['mipnerf', 'freenerf']
  with pytest.raises(ValueError, match="--precisions 'fp16': expected comma-separated names among"):
    device.main(['--precisions', 'fp16'])


def test_regnerf_steps_with_as_many_random_pose_rays_as_training_rays(tmp_path):
  out = tmp_path / 'results.json'
  device.main(['--tiny', '--batch_size', '64', '--repeats', '1', '--render_rays', '64', '--methods',
               'mipnerf,regnerf', '--precisions', 'float32', '--out', str(out)])
  report = json.loads(out.read_text())
  methods = report['results']['float32']['methods']
  # One 8 x 8 patch of random-pose rays: the density trunk forward and backward again on both levels.
  assert 1.3 < methods['regnerf']['step_tflop'] / methods['mipnerf']['step_tflop'] < 2.2
  assert report['provenance']['command'] == report['command'] and report['provenance']['commit']
