"""lab.study.estimate and `lab.study --list --estimate`: a study's expected wall time before it runs."""

import json
import os
import pathlib
import subprocess
import sys

import pytest

from internal import configs
from lab.study import estimate
from lab.study import spec as study_spec

REPO = pathlib.Path(__file__).resolve().parents[1]
TINY = f'''
name = "cost"
seeds = 2
bindings = ["MLP.net_depth = 2", "MLP.net_width = 16", "MLP.net_width_viewdirs = 16",
            "MipNerfModel.num_samples = 8", "Config.batch_size = 64", "Config.max_steps = 40",
            "Config.compute_lpips = False", "Config.render_chunk_size = 192", "Config.curve_every = 10",
            "Config.generated_size = (12, 16)", "Config.data_dir = '{{out}}/scenes/{{scene}}'"]
[methods.freenerf]
configs = ["{REPO}/configs/demo.gin"]
[scenes.object]
bindings = ["Config.generated_rig = 'object'"]
'''


def test_cell_seconds_scale_the_measurement():
  config = configs.Config(max_steps=1000, curve_every=100, curve_test_ids=(0, 1), curve_factor=4, eval_factor=1)
  measured = {'setup_seconds': 30., 'step_seconds': .2, 'view_seconds': 3.2, 'eval_views': 5, 'curve_views': 2}
  seconds = estimate.cell_seconds(config, measured)
  # 10 curve points x 2 views at 1/16 of the pixels of an evaluated view.
  assert seconds == {'train': pytest.approx(30. + 200. + 10 * 2 * 3.2 / 16), 'eval': pytest.approx(16.)}


def test_signature_ignores_seeds_run_folder_and_name():
  spec = {'gin_configs': ['a.gin'], 'gin_bindings': ['Config.max_steps = 5', 'Config.jax_rng_seed = 1',
                                                     'Config.np_rng_seed = 1', "Config.checkpoint_dir = 'x'"]}
  other = {'gin_configs': ['a.gin'], 'gin_bindings': ['Config.max_steps = 5', 'Config.jax_rng_seed = 2',
                                                      'Config.np_rng_seed = 2', "Config.expname = 'y'"]}
  assert estimate.signature(spec) == estimate.signature(other)
  assert estimate.signature(spec) != estimate.signature({**spec, 'gin_bindings': ['Config.max_steps = 6']})


def test_durations_read_as_a_person_would():
  assert [estimate.format_duration(s) for s in (40, 720, 3900)] == ['40 s', '12 min', '1 h 05 min']


def test_list_estimate_measures_each_setting_once(tmp_path):
  path = tmp_path / 'cost.toml'
  path.write_text(TINY)
  out = str(tmp_path / 'out')
  result = subprocess.run([sys.executable, '-m', 'lab.study', str(path), '--out', out, '--list', '--estimate'],
                          cwd=REPO, capture_output=True, text=True, timeout=600, check=True)
  lines = result.stdout.splitlines()
  assert sum(line.startswith('measuring') for line in lines) == 1  # Two seeds, one setting.
  estimates = [line for line in lines if line.startswith('estimate')]
  assert len(estimates) == 2 and estimates[0].split('(')[0] == estimates[1].split('(')[0]
  assert lines[-1].startswith('total for 2 pending cell(s): ')
  assert not list(pathlib.Path(out).rglob('checkpoints'))  # Nothing trained in the cells' folders.


def test_estimate_needs_list(tmp_path):
  path = tmp_path / 'cost.toml'
  path.write_text(TINY)
  result = subprocess.run([sys.executable, '-m', 'lab.study', str(path), '--estimate'], cwd=REPO,
                          capture_output=True, text=True, check=False)
  assert result.returncode == 2 and '--estimate goes with --list' in result.stderr


BENCH = {'device': 'GPU X', 'jax_version': '0', 'batch_size': 4096,
         'results': {'float32': {'methods': {'mipnerf': {'step_seconds': 0.1}, 'freenerf': {'step_seconds': 0.3}}},
                     'bfloat16': {'methods': {'mipnerf': {'step_seconds': 0.02}}}}}


def _cpu_ratio():
  methods = json.loads((REPO / estimate.CPU_RATIO_FILE).read_text())['results']['float32']['methods']
  return methods['regnerf']['step_seconds'] / methods['mipnerf']['step_seconds']


def test_gpu_step_seconds_per_precision_method_and_batch():
  assert estimate.gpu_step_seconds(BENCH, 'float32', 'freenerf', 4096) == (0.3, '')
  seconds, note = estimate.gpu_step_seconds(BENCH, 'float32', 'regnerf', 4096)
  assert 1.5 < _cpu_ratio() < 2.2 and seconds == pytest.approx(0.1 * _cpu_ratio())
  assert note == (f"regnerf not benchmarked: mip-NeRF's step x {_cpu_ratio():.2f}, as measured on a CPU "
                  f'({estimate.CPU_RATIO_FILE}), not yet on a GPU')
  seconds, note = estimate.gpu_step_seconds({**BENCH, 'results': {'float32': {'methods': {
      'freenerf': {'step_seconds': 0.3}, 'nerf': {'step_seconds': 0.1}}}}}, 'float32', 'regnerf', 4096)
  assert seconds == pytest.approx(0.2) and note == 'regnerf not benchmarked: the mean of freenerf, nerf'
  seconds, note = estimate.gpu_step_seconds(BENCH, 'bfloat16', 'mipnerf', 1024)
  assert seconds == pytest.approx(0.005) and note == 'batch 1024 scaled from 4096'
  with pytest.raises(ValueError, match=r"Config.precision 'default' has no GPU step time.*\['bfloat16', 'float32'\]"):
    estimate.gpu_step_seconds(BENCH, 'default', 'mipnerf', 4096)


def _device_record(path, date, regnerf_ms, precision='bfloat16'):
  path.parent.mkdir(parents=True, exist_ok=True)
  path.write_text(json.dumps({'device': f'GPU of {date}', 'provenance': {'date': date}, 'results': {precision: {
      'methods': {'mipnerf': {'step_seconds': 0.02}, 'regnerf': {'step_seconds': regnerf_ms / 1e3}}}}}))


def test_regnerf_costs_the_ratio_a_gpu_window_timed_once_one_did(tmp_path, monkeypatch):
  monkeypatch.setattr(estimate, 'REPO', str(tmp_path))
  _device_record(tmp_path / estimate.CPU_RATIO_FILE, '2026-01-01', 40, 'float32')
  assert estimate.regnerf_ratio('bfloat16')[0] == pytest.approx(2.)
  variants = tmp_path / 'results' / 'gpu' / 'ledger' / 'variants'
  _device_record(variants / 'nvidia_h100_abc' / 'bench_device.json', '2026-12-02', 34)
  _device_record(variants / 'nvidia_h200_abc' / 'bench_device.json', '2026-12-01', 30)
  ratio, where = estimate.regnerf_ratio('bfloat16')
  newest = os.path.relpath(variants / 'nvidia_h100_abc' / 'bench_device.json', tmp_path)
  assert ratio == pytest.approx(1.7) and where == f'as timed on GPU of 2026-12-02 ({newest})'


def test_wall_seconds_packs_the_longest_cells_first():
  assert estimate.wall_seconds([3., 3., 2., 2., 2.], 2) == 7.   # 3+2+2 | 3+2, as longest-first packs them.
  assert estimate.wall_seconds([3., 1., 2.], 1) == 6. and estimate.wall_seconds([3., 1., 2.], 10) == 3.
  assert estimate.wall_seconds([], 4) == 0.


def test_cluster_estimate_of_the_dtu_table_from_the_committed_gpu_record():
  assert study_spec.load(REPO / 'studies' / 'table_dtu.toml').resources == study_spec.Resources(1, 4, 3)
  bench = json.loads(next((REPO / 'results' / 'gpu').glob('bench_device_*.json')).read_text())
  out = subprocess.run([sys.executable, '-m', 'lab.study', 'studies/table_dtu.toml', '--list', '--estimate',
                        '--cluster-gpus', '8'], cwd=REPO, capture_output=True, text=True, check=True).stdout
  lines = out.splitlines()
  assert lines[0] == 'studies/table_dtu.toml: 135 pending cell(s) estimated, 0 done not counted'
  # The cells run at Config.precision = 'auto': bfloat16 on the GPUs they are estimated for, not this CPU's float32.
  step = bench['results']['bfloat16']['methods']['freenerf']['step_seconds']
  assert f'{43945 * step / 3600:8.2f} GPU-h  43945 steps x {step * 1e3:.1f} ms (bfloat16)  freenerf__scan8__views=3' in lines
  per_view = {3: 43945, 6: 87891, 9: 131836}
  steps = {m: bench['results']['bfloat16']['methods'][m]['step_seconds'] for m in ('freenerf', 'mipnerf')}
  regnerf = steps['mipnerf'] * _cpu_ratio()
  total = 15 * sum(n * (steps['freenerf'] + steps['mipnerf'] + regnerf) for n in per_view.values()) / 3600
  for label in ('as configured', "all at Config.precision = 'bfloat16'"):
    assert f'total {label}: 135 cell(s), {total:.1f} GPU-hours; on 8 GPU(s)' in out
  assert f"x {regnerf * 1e3:.1f} ms (bfloat16)  regnerf__scan8__views=3  [regnerf not benchmarked: mip-NeRF's" in out
