"""bench/gpu_check.sh, the checks for a lent GPU, run end to end on the CPU at a tiny size (so it does not rot)."""

import json
import os
import subprocess
import sys

import pytest

from bench import device
from conftest import SHARED_DATA

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = device.TINY + ['Config.batch_size = 64', 'Config.render_chunk_size = 4096', 'Config.occ_reg_range = 4']


@pytest.mark.skipif(not (SHARED_DATA / 'dtu' / 'dtu_scan24').is_dir(), reason=f'no DTU scan24 under {SHARED_DATA}')
def test_gpu_check_runs_every_stage_on_a_packed_dtu_scan(tmp_path):
  scene = tmp_path / 'scan24.npz'
  subprocess.run([sys.executable, '-m', 'tools.pack_scene', '--gin_configs=configs/freenerf/dtu3_freenerf.gin',
                  '--gin_bindings', f"Config.data_dir = '{SHARED_DATA / 'dtu'}'", "Config.dtu_scan = 'dtu_scan24'",
                  'Config.allow_missing_test_views = True', "Config.dtu_mask_path = ''", '--out', str(scene)],
                 cwd=ROOT, check=True, capture_output=True)
  env = dict(os.environ, PYTHON=sys.executable, DTU_SCAN='dtu_scan24', RUN_DIR=str(tmp_path / 'run'), STEPS='20',
             EXTRA_BINDINGS='\n'.join(TINY), TEST_FILES='tests/test_trig.py')
  out = tmp_path / 'out'
  result = subprocess.run(['bash', 'bench/gpu_check.sh', str(scene), str(out), '5'], cwd=ROOT, env=env, text=True,
                          capture_output=True, timeout=600)
  assert result.returncode == 0, result.stdout + result.stderr
  for stage in ('env', 'train', 'eval', 'tests'):  # STEPS skips the benchmark.
    assert f'== {stage}: status 0' in result.stdout, result.stdout
  assert 'jax backend: cpu' in (out / 'env.log').read_text()
  assert json.loads((out / 'metrics.json').read_text())['step'] == 20
  assert (out / 'test_views.png').stat().st_size > 0 and not (out / 'bench.log').exists()
