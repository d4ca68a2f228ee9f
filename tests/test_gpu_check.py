"""lab/gpu_check.sh, the checks for a lent GPU, run end to end on the CPU at a tiny size (so it does not rot)."""

import json
import os
import subprocess
import sys

import pytest

from bench import device
from conftest import SHARED_DATA

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACK = ['Config.allow_missing_test_views = True', "Config.dtu_mask_path = ''", 'Config.eval_factor = 8']
TINY = device.TINY + PACK + ['Config.batch_size = 64', 'Config.render_chunk_size = 4096', 'Config.occ_reg_range = 4']


@pytest.mark.slow
@pytest.mark.skipif(not (SHARED_DATA / 'dtu' / 'dtu_scan24').is_dir(), reason=f'no DTU scan24 under {SHARED_DATA}')
def test_gpu_check_runs_every_stage_and_reports_the_three_tables(tmp_path):
  scene = tmp_path / 'scan24.npz'
  subprocess.run([sys.executable, '-m', 'tools.pack_scene', '--gin_configs=configs/freenerf/dtu3_freenerf.gin',
                  '--gin_bindings', f"Config.data_dir = '{SHARED_DATA / 'dtu'}'", "Config.dtu_scan = 'dtu_scan24'",
                  *PACK, '--out', str(scene)], cwd=ROOT, check=True, capture_output=True)
  env = dict(os.environ, PYTHON=sys.executable, DTU_SCAN='dtu_scan24', RUN_ROOT=str(tmp_path / 'runs'),
             RUNS='freenerf:bfloat16:20:pallas', EXTRA_BINDINGS='\n'.join(TINY),
             TEST_FILES='tests/test_activations.py',
             VARIANT_FLAGS='--tiny --batch_size 64 --repeats 1 --precisions bfloat16 '
                           '--variants relu_from_output,pallas --profile_steps 1')
  out = tmp_path / 'out'
  result = subprocess.run(['bash', 'lab/gpu_check.sh', str(scene), str(out)], cwd=ROOT, env=env, text=True,
                          capture_output=True, timeout=600)
  assert result.returncode == 0, result.stdout + result.stderr
  for stage in ('env', 'step_variants', 'train_freenerf_bfloat16_pallas', 'eval_freenerf_bfloat16_pallas', 'tests'):
    assert f'== {stage}: status 0' in result.stdout, result.stdout
  assert 'jax backend: cpu' in (out / 'env.log').read_text()
  assert json.loads((out / 'metrics_freenerf_bfloat16_pallas.json').read_text())['step'] == 20
  assert "MLP.dense_kernel = 'pallas'" in (tmp_path / 'runs' / 'freenerf_bfloat16_pallas' / 'config.gin').read_text()
  variants = json.loads((out / 'step_variants.json').read_text())['results']['bfloat16']
  assert variants['relu_from_output']['params_equal'] and 'profile' in variants['base']
  assert abs(variants['pallas']['loss_difference']) < 1e-2 * variants['base']['loss']  # Interpreted on the CPU.
  report = (out / 'gpu_report.md').read_text()
  assert report in result.stdout  # Printed last.
  for heading in ('## Step variants', '## Kernel profiles', '## Precision trade',
                  '| bfloat16 | freenerf | pallas | 20 |'):
    assert heading in report
  assert (out / 'test_views.png').stat().st_size > 0 and (out / 'trace_bfloat16_base.json.gz').is_file()
  assert sorted(p.name for p in (out / 'test_truth').iterdir()) == sorted(
      p.name for p in (out / 'test_preds_freenerf_bfloat16_pallas').glob('color_*.png'))  # The picture's truth.
