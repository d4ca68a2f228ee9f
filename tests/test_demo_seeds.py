"""tools.demo_seeds: the commands it runs per seed, what it records and summarizes, what it refuses."""

import json
import os
import pathlib
import statistics
import sys

import pytest

from internal import cli
from internal import demo
from internal import environment
from internal.evaluation import learning_curve
from tools import demo_seeds


def _record(seed: int, nerf: float, free: float, all_views: float, seconds: float) -> dict:
  means = lambda psnr: {'psnr': psnr, 'ssim': psnr / 100, 'lpips': None, 'depth_mae': 1.}
  return {'seed': seed, 'step': 700,
          'demo': {'command': 'python train.py', 'seconds': seconds, 'load_average': [0.5, 1.25],
                   'means': {'NeRF': means(nerf), 'FreeNeRF': means(free)}},
          'all_views': {'commands': [], 'seconds': 100., 'means': means(all_views)},
          'provenance': {'command': 'python -m tools.demo_seeds --seeds 1', 'commit': 'abc', 'date': 'today',
                         'machine': {'cpu_count': 2, 'cpu': 'X', 'jax': '0.1', 'isa': 'AVX2'}}}


def test_the_demo_seed_runs_plain_train_py_and_another_seed_binds_it():
  commands = demo_seeds.commands(demo_seeds.DEFAULT_SEED)
  assert demo_seeds.shown(commands['demo']) == 'python train.py'
  commands = demo_seeds.commands(7, ['Config.max_steps = 4'])
  assert demo_seeds.shown(commands['demo']) == ('python train.py --gin_bindings "Config.max_steps = 4" '
                                                '"Config.jax_rng_seed = 7"')
  train, evaluate = (demo_seeds.shown(argv) for argv in commands['all_views'])
  flags = ('--gin_configs configs/demo.gin configs/demo_forward.gin configs/demo_nerf.gin --gin_bindings '
           '"Config.n_input_views = 0" "Config.compute_lpips = False" "Config.checkpoint_dir = \'out/all_views\'" '
           '"Config.max_steps = 4" "Config.jax_rng_seed = 7"')
  assert (train, evaluate) == ('python train.py ' + flags, 'python eval.py ' + flags)


def test_summary_and_readme_over_the_seeds(tmp_path):
  kind = tmp_path / 'AVX2'
  kind.mkdir()
  for record in (_record(2, 16., 19.5, 22., 300.), _record(1, 18., 21., 26., 320.)):
    (kind / f'seed_{record["seed"]}.json').write_text(json.dumps(record))
  table = demo_seeds.write_summary(str(kind))
  assert list(table['rows']) == ['1', '2']
  assert table['rows']['2']['FreeNeRF lead psnr'] == pytest.approx(3.5)
  lead = table['over_seeds']['FreeNeRF lead psnr']
  assert (lead['n'], lead['mean'], lead['min'], lead['max']) == (2, 3.25, 3., 3.5)
  assert lead['std'] == pytest.approx(statistics.stdev([3., 3.5]))
  assert 'NeRF lpips' not in table['rows']['1']  # Not measured: no column.
  readme = (kind / demo_seeds.README).read_text()
  assert readme.startswith('# The demo over seeds: AVX2 machines')
  assert '| 1 | 18.00 | 21.00 | 0.180 | 0.210 | 1.000 | 1.000 | 3.00 | 26.00 | 320 | 100 |' in readme
  assert '| std | 1.41 | 1.06 |' in readme
  assert ('- seed 2: commit abc, today, 2 CPUs (X), XLA for AVX2, jax 0.1, load average 0.5 before and 1.25 after '
          'the demo;') in readme
  assert json.loads((kind / demo_seeds.SUMMARY).read_text()) == json.loads(json.dumps(table))
  (tmp_path / 'notes').mkdir()  # A folder without a summary is no kind.
  index = demo_seeds.index(str(tmp_path))
  assert index.count('\n| ') == 2 and '| AVX2 | 2 | 17.00 | 20.25 | 3.00 | 310 | [AVX2/](AVX2/README.md) |' in index


def test_records_go_to_the_folder_of_the_machine_kind_xla_compiles_for(tmp_path, monkeypatch):
  monkeypatch.setenv('XLA_FLAGS', '--xla_cpu_max_isa=AVX2')
  assert environment.cpu_isa() in ('AVX2', 'AVX', 'SSE4_2') or not environment.cpu_isa().startswith(('AVX', 'SSE'))
  assert demo_seeds.kind_dir(str(tmp_path)) == str(tmp_path / environment.cpu_isa())


def test_a_recorded_seed_or_a_used_work_folder_is_refused(tmp_path, monkeypatch, capsys):
  recorded = pathlib.Path(demo_seeds.kind_dir(str(tmp_path / 'out')))
  recorded.mkdir(parents=True)
  (recorded / 'seed_3.json').write_text('{}')
  (tmp_path / 'work' / 'seed_4').mkdir(parents=True)
  for seed, what in ((3, 'seed 3 is recorded'), (4, 'its runs would resume')):
    monkeypatch.setattr(sys, 'argv', ['demo_seeds', '--seeds', str(seed), '--out', str(tmp_path / 'out'),
                                      '--work', str(tmp_path / 'work')])
    assert cli.run(demo_seeds.main) == 2
    err = capsys.readouterr().err
    assert err.startswith('error: ') and what in err and err.count('\n') == 1, err
  assert (recorded / 'seed_3.json').read_text() == '{}'


def test_a_failed_command_names_itself_and_its_log(tmp_path):
  log = tmp_path / 'log.txt'
  with pytest.raises(RuntimeError, match=r"python -c .*failed in .*; its output is in .*log.txt"):
    demo_seeds.run_timed([[sys.executable, '-c', 'print("why"); raise SystemExit(3)']], str(tmp_path), str(log))
  assert log.read_text() == 'why\n'


@pytest.mark.parametrize('seeds, message', [
    (['abc'], "--seeds 'abc': expected whole numbers (values of Config.jax_rng_seed)"),
    (['1180591620717411303424'], '--seeds 1180591620717411303424: Config.jax_rng_seed = 1180591620717411303424; '
                                 'expected a whole number in [0, 2^63)'),
    (['5', '5'], '--seeds 5 5: seed 5 is given twice; expected each seed once')])
def test_a_bad_seed_is_one_line_before_any_work_and_leaves_nothing(tmp_path, monkeypatch, capsys, seeds, message):
  monkeypatch.setattr(demo_seeds, 'run_seed', lambda *args: pytest.fail('a demo ran before the seeds were checked'))
  out, work = tmp_path / 'out', tmp_path / 'work'
  assert cli.run(lambda: demo_seeds.main(['--seeds', *seeds, '--out', str(out), '--work', str(work)])) == 2
  err = capsys.readouterr().err
  assert err.startswith(f'error: {message}') and err.count('\n') == 1, err
  assert not out.exists() and not work.exists()


def test_a_seed_records_each_methods_learning_curve(tmp_path, monkeypatch):
  def trained(argv_list, cwd, log):  # The demo (the first command) leaves each run's learning_curve.csv.
    for i, cfg in enumerate(demo.method_configs([]).values()):
      if not os.path.isdir(os.path.join(cwd, cfg.checkpoint_dir)):
        os.makedirs(os.path.join(cwd, cfg.checkpoint_dir))
        learning_curve.CurveLog(os.path.join(cwd, cfg.checkpoint_dir), 0).append(
            {'step': 50, 'psnr': 19.4 + i, 'seconds': 1.5})
    return 1.
  monkeypatch.setattr(demo_seeds, 'run_timed', trained)
  monkeypatch.setattr(demo_seeds, 'means', lambda run, step: {'psnr': 17.})
  record = demo_seeds.run_seed(7, str(tmp_path))
  assert len(record['demo']['load_average']) == 2 and min(record['demo']['load_average']) >= 0
  assert record['demo']['learning_curves'] == {name: [{'step': 50, 'psnr': 19.4 + i, 'seconds': 1.5}]
                                               for i, name in enumerate(demo.METHODS)}
