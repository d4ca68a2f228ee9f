"""bench.demo_cost: alternating runs, medians and ratios, the README over kinds, refusals."""

import json

import gin
import pytest

from bench import demo_cost
from internal import demo


def test_runs_alternate_and_the_ratio_is_of_the_medians(tmp_path, monkeypatch):
  calls = []

  def fake_run(bindings, cwd):
    calls.append(cwd.rsplit('/', 1)[-1])
    cost = 100. if bindings else 60. + len(calls)  # The former length costs 100; now 61, 63, 65.
    return {'wall_seconds': 2 * cost, 'cpu_seconds': cost, 'load_average': [0., 0.], 'psnr': {}}

  monkeypatch.setattr(demo_cost, 'run_demo', fake_run)
  record = demo_cost.measure(3, str(tmp_path))
  assert calls == ['now_0', 'former_0', 'now_1', 'former_1', 'now_2', 'former_2']
  assert record['median'] == {'now': {'wall_seconds': 126., 'cpu_seconds': 63.},
                              'former': {'wall_seconds': 200., 'cpu_seconds': 100.}}
  assert record['ratio_now_to_former'] == {'wall_seconds': .63, 'cpu_seconds': .63}


def test_the_readme_gives_each_kind_its_row(tmp_path):
  for kind, now in (('AVX2', 50.), ('AVX512', 30.)):
    record = {'runs': {'now': [{}], 'former': [{}]}, 'ratio_now_to_former': {'cpu_seconds': now / 100},
              'median': {'now': {'wall_seconds': now, 'cpu_seconds': now},
                         'former': {'wall_seconds': 100., 'cpu_seconds': 100.}}}
    (tmp_path / f'{kind}.json').write_text(json.dumps(record))
  rows = demo_cost.readme(str(tmp_path)).splitlines()[-2:]
  assert rows[0].startswith('| AVX2 | 1 | 50.0 | 100.0 | 50.0 | 100.0 | 0.500 |')
  assert rows[1].startswith('| AVX512 | 1 | 30.0 | 100.0 | 30.0 | 100.0 | 0.300 |')


def test_a_recorded_kind_and_a_used_work_folder_are_refused(tmp_path, monkeypatch):
  monkeypatch.setattr(demo_cost.environment, 'cpu_isa', lambda: 'AVX2')
  (tmp_path / 'AVX2.json').write_text('{}')
  with pytest.raises(FileExistsError, match='AVX2.json.* exists: this machine kind is recorded'):
    demo_cost.main(['--out', str(tmp_path), '--work', str(tmp_path / 'work')])
  (tmp_path / 'work').mkdir()
  with pytest.raises(FileExistsError, match="work' exists: its runs would resume"):
    demo_cost.main(['--out', str(tmp_path / 'other'), '--work', str(tmp_path / 'work')])


@pytest.mark.parametrize('bindings, steps, coarse', [([], 500, 16), (demo_cost.FORMER, 700, 32)])
def test_the_former_bindings_give_the_demo_its_former_length(bindings, steps, coarse):
  with demo.method_config('FreeNeRF', bindings) as config:
    assert (config.max_steps, gin.query_parameter('NerfModel.num_coarse_samples')) == (steps, coarse)
