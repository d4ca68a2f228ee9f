"""tools.study's executors on one tiny 4-cell study: one process, two processes sharing the folder, and Ray (a real
cluster started with `ray start --head`; skipped without the cluster extra); each cell trained once and the same
results.csv to the last digit (training is deterministic). Also a Ray worker killed mid-cell, then Ctrl-C; and SIGTERM
to a driver of either executor."""

import csv
import http.server
import json
import os
import pathlib
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

import pytest

from conftest import JAX_CACHE
from test_study import STEPS
from test_study import TINY_STUDY
from tools.study import claim as study_claim

REPO = pathlib.Path(__file__).resolve().parents[1]
STUDY = TINY_STUDY.replace('"Config.curve_every = 10", "Config.curve_factor = 1",', '"Config.eval_test_ids = [0, 1]",')
COMPARED = ('cell', 'method', 'scene', 'status', 'step', 'complete', 'psnr', 'ssim', 'depth_mae',
            'depth_within_1pct', 'depth_within_5pct', 'steps_trained')
NO_RAY = 'the cluster extra is not installed (pip install -r requirements-cluster.txt)'
# Ray's token authentication off for the clusters here, whatever token the machine's ~/.ray holds.
ENV = {**os.environ, 'JAX_COMPILATION_CACHE_DIR': JAX_CACHE, 'JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS': '0',
       'RAY_AUTH_MODE': 'disabled'}


def _study(tmp_path, steps=STEPS, every=10, one_cell=False):
  """The tiny study (one_cell: FreeNeRF on the object scene only) with its steps and checkpoint interval -> path."""
  text = STUDY.replace(f'Config.max_steps = {STEPS}', f'Config.max_steps = {steps}').replace(
      'Config.checkpoint_every = 10', f'Config.checkpoint_every = {every}')
  if one_cell:
    text = text.split('[methods.mipnerf]')[0] + '[scenes.object]\nbindings = ["Config.generated_rig = \'object\'"]\n'
  path = tmp_path / 'mini.toml'
  path.write_text(text)
  return path


def _study_command(path, out, *flags):
  return [sys.executable, '-m', 'tools.study', str(path), '--out', str(out), *flags]


def _results(out):
  with open(pathlib.Path(out) / 'mini' / 'results.csv', newline='') as f:
    return [{k: row[k] for k in COMPARED} for row in csv.DictReader(f)]


def _trained_once(out):
  """Each cell's log holds exactly one cell record: no cell was trained (or written) twice."""
  for log in pathlib.Path(out, 'mini').glob('*/log.txt'):
    assert log.read_text().count('"steps_trained"') == 1, log.read_text()[-2000:]


@pytest.fixture(scope='module', name='reference')
def fixture_reference(tmp_path_factory):
  """(study file, results rows) of the study run by one process, two cells at a time."""
  root = tmp_path_factory.mktemp('executors')
  path = _study(root)
  subprocess.run(_study_command(path, root / 'one', '--jobs', '2'), cwd=REPO, env=ENV, check=True,
                 capture_output=True, text=True)
  rows = _results(root / 'one')
  assert len(rows) == 4 and all(r['status'] == 'done' and r['steps_trained'] == str(STEPS) for r in rows)
  return path, rows


def _run_together(*commands) -> list:
  """Runs the commands at once; their outputs (stdout and stderr), asserting that each exits 0."""
  runners = [subprocess.Popen(c, cwd=REPO, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for c in commands]
  outputs = [r.communicate(timeout=600)[0] for r in runners]
  assert [r.returncode for r in runners] == [0] * len(runners), [o[-3000:] for o in outputs]
  return outputs


@pytest.mark.slow
def test_two_processes_on_one_folder_train_each_cell_once(reference, tmp_path):
  path, rows = reference
  out = tmp_path / 'two'
  _run_together(_study_command(path, out), _study_command(path, out, '--shard', '1/2'))
  assert _results(out) == rows
  _trained_once(out)
  assert not list(out.glob(f'mini/*/{study_claim.CLAIM_FILE}*'))             # Every claim released.


def _free_port() -> int:
  with socket.socket() as s:
    s.bind(('127.0.0.1', 0))
    return s.getsockname()[1]


def _processes_mentioning(text: str) -> list:
  """Ids of the processes whose command line contains text."""
  found = []
  for proc in pathlib.Path('/proc').glob('[0-9]*'):
    try:
      if text in proc.joinpath('cmdline').read_bytes().decode(errors='replace'):
        found.append(int(proc.name))
    except OSError:
      pass
  return found


@pytest.fixture(scope='module', name='cluster')
def fixture_cluster():
  """The address of a local Ray cluster started as on a head node, `ray start --head`, in its own process."""
  pytest.importorskip('ray', reason=NO_RAY)
  port = _free_port()
  temp = tempfile.mkdtemp(prefix='ray')  # Short: Ray's socket paths live under it.
  head = subprocess.Popen([os.path.join(os.path.dirname(sys.executable), 'ray'), 'start', '--head', '--block',
                           f'--port={port}', '--num-cpus=2', '--include-dashboard=false', '--disable-usage-stats',
                           f'--temp-dir={temp}'], env={**ENV, 'PYTHONPATH': str(REPO)}, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True)
  for line in head.stdout:
    if 'Ray runtime started' in line:
      break
  yield f'127.0.0.1:{port}'
  head.send_signal(signal.SIGTERM)  # Stops the cluster it started.
  head.wait(60)
  shutil.rmtree(temp, ignore_errors=True)


@pytest.mark.slow
def test_ray_beside_a_local_shard_gives_the_local_executors_results(reference, cluster, tmp_path):
  path, rows = reference
  out = tmp_path / 'ray'
  ray_output, _ = _run_together(_study_command(path, out, '--executor', 'ray', '--address', cluster, '--num-cpus', '1'),
                                _study_command(path, out, '--shard', '0/2'))
  assert _results(out) == rows
  _trained_once(out)
  assert 'cells: 100%' in ray_output and 'failed 0' in ray_output


def test_the_overhead_benchmark_records_both_executors(cluster, tmp_path):
  out = tmp_path / 'overhead.json'
  result = subprocess.run([sys.executable, '-m', 'tools.study.executor_overhead', '--cells', '2', '--address', cluster,
                           '--out', str(out)], cwd=REPO, env=ENV, capture_output=True, text=True, timeout=600,
                          check=False)
  assert result.returncode == 0, result.stderr[-3000:]
  record = json.loads(out.read_text())
  assert record['command'].startswith('python -m tools.study.executor_overhead --cells 2') and record['cluster'] == cluster
  for name, cells in (('local', 2), ('ray', 1)):  # Ray's first cell (its worker starting) is recorded apart.
    assert record[name]['cells'] == cells and record[name]['cell_startup_median_s'] > 0.
  for times in record['per_cell']['local'] + record['per_cell']['ray']:
    assert times['outer'] >= times['inner'] > 0.


def _wait_for(predicate, what, timeout=300.):
  deadline = time.time() + timeout
  while not predicate():
    assert time.time() < deadline, f'timed out waiting for {what}'
    time.sleep(0.2)


def _latest_step(run_dir):
  """The newest step folder of the run's checkpoints (orbax writes it under a temporary name first), or None."""
  folder = run_dir / 'checkpoints'
  return max((int(n) for n in os.listdir(folder) if n.isdigit()), default=None) if folder.is_dir() else None


@pytest.mark.slow
def test_a_killed_worker_is_retried_from_its_checkpoint_and_ctrl_c_stops_cleanly(cluster, tmp_path):
  path = _study(tmp_path, steps=4000, every=200, one_cell=True)
  out, cell = tmp_path / 'out', tmp_path / 'out' / 'mini' / 'freenerf__object'
  command = _study_command(path, out, '--executor', 'ray', '--address', cluster)
  driver = subprocess.Popen(command, cwd=REPO, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
  _wait_for(lambda: (_latest_step(cell / 'run') or 0) >= 400, 'the first checkpoints')
  first = json.loads((cell / study_claim.CLAIM_FILE).read_text())
  worker = int(pathlib.Path(f'/proc/{first["pid"]}/stat').read_text().split(')')[1].split()[1])
  os.kill(worker, signal.SIGKILL)                                  # Its node's worker dies in the middle of the cell.
  _wait_for(lambda: (cell / study_claim.CLAIM_FILE).exists() and json.loads(
      (cell / study_claim.CLAIM_FILE).read_text())['pid'] != first['pid'], 'the retry')
  killed_at = _latest_step(cell / 'run')
  _wait_for(lambda: (_latest_step(cell / 'run') or 0) > killed_at, 'the retry to train on')
  for _ in range(4):  # Ctrl-C, and again while the cell saves: the cell stops once, its stop checkpoint complete.
    driver.send_signal(signal.SIGINT)
    time.sleep(0.5)
  output = driver.communicate(timeout=300)[0]
  assert driver.returncode == 128 + signal.SIGINT and 'interrupted:' in output, output[-3000:]
  assert 'still stopping: the cells save their checkpoints' in output, output[-3000:]
  assert 'Traceback' not in output and not (cell / 'cell.json').exists(), output[-3000:]
  stopped_at = _stopped_cleanly(cell)
  assert stopped_at > killed_at, (stopped_at, killed_at)
  _resumed_from(command, cell, stopped_at)


@pytest.mark.slow
@pytest.mark.parametrize('executor', ['ray', 'local'])
def test_sigterm_to_a_driver_stops_its_cells_as_ctrl_c_does(request, tmp_path, executor):
  """A scheduler's SIGTERM to the driver: its running cell saves a checkpoint and releases its claim before the
  driver exits (143), rather than training on after the driver is gone (Ray's own handler just exited)."""
  path = _study(tmp_path, steps=4000, every=100, one_cell=True)
  out, cell = tmp_path / 'out', tmp_path / 'out' / 'mini' / 'freenerf__object'
  flags = ['--executor', 'ray', '--address', request.getfixturevalue('cluster')] if executor == 'ray' else []
  command = _study_command(path, out, *flags)
  driver = subprocess.Popen(command, cwd=REPO, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
  _wait_for(lambda: (_latest_step(cell / 'run') or 0) >= 100, 'the first checkpoint')
  driver.send_signal(signal.SIGTERM)
  output = driver.communicate(timeout=300)[0]
  assert driver.returncode == 128 + signal.SIGTERM and output.rstrip().endswith(
      'terminated: stopped by SIGTERM before the command finished; its cells saved their checkpoints, what it wrote '
      'is kept, and the same command run again finishes the work'), output[-3000:]
  assert 'Traceback' not in output and not (cell / 'cell.json').exists(), output[-3000:]
  assert 100 <= _stopped_cleanly(cell) < 4000


STOPPED = re.compile(r'stopped by signal 2 at step (\d+) with a checkpoint saved; the study run again resumes it$')


def _stopped_cleanly(cell) -> int:
  """The step at which the cell's process stopped, after checking that its log ends in its one stop line (no
  traceback, no interrupted save) and that its newest checkpoint, complete, is that step."""
  log = (cell / 'log.txt').read_text()
  assert not re.search('Traceback|KeyboardInterrupt|interrupted:|thread failed|Failed to run', log), log[-3000:]
  match = STOPPED.search(log.strip().splitlines()[-1])
  assert match, log[-3000:]
  step = int(match.group(1))
  assert _latest_step(cell / 'run') == step and not any('tmp' in n for n in os.listdir(cell / 'run' / 'checkpoints'))
  assert not (cell / study_claim.CLAIM_FILE).exists() and not (cell / study_claim.STOP_FILE).exists()
  return step


def _resumed_from(command, cell, step: int) -> None:
  """Runs the study again: its cell resumes from step and finishes."""
  rerun = subprocess.run(command, cwd=REPO, env=ENV, capture_output=True, text=True, timeout=600, check=False)
  assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
  record = json.loads((cell / 'cell.json').read_text())
  assert record['resumed_from_step'] == step and record['step'] == record['steps_trained'] + step


@pytest.mark.slow
def test_a_cell_sent_signal_after_signal_stops_once_saving_the_step_it_stopped_at(tmp_path):
  """SIGINT and SIGTERM every 5 ms to a cell process of the local executor from its first checkpoint on, through
  its stop checkpoint, until it exits: the first stops it, the others find it stopping (as when Ray, its claim's
  stop request, its runner and a user all ask)."""
  path = _study(tmp_path, steps=2000, every=50, one_cell=True)
  out, cell = tmp_path / 'out', tmp_path / 'out' / 'mini' / 'freenerf__object'
  command = _study_command(path, out)
  runner = subprocess.Popen(command, cwd=REPO, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
  _wait_for(lambda: (_latest_step(cell / 'run') or 0) >= 50, 'the first checkpoint')
  process = os.pidfd_open(json.loads((cell / study_claim.CLAIM_FILE).read_text())['pid'])
  sent = 0
  try:
    while True:
      signal.pidfd_send_signal(process, (signal.SIGINT, signal.SIGTERM)[sent % 2])
      sent += 1
      time.sleep(0.005)
  except ProcessLookupError:  # It has exited.
    os.close(process)
  output = runner.communicate(timeout=300)[0]
  assert sent > 20 and 'exit status 130' in output, output[-3000:]  # Signalled before its stop and after it.
  step = _stopped_cleanly(cell)
  assert 50 <= step < 2000
  _resumed_from(command, cell, step)


@pytest.mark.slow
def test_the_sbatch_script_runs_a_study_on_a_one_node_allocation(tmp_path):
  pytest.importorskip('ray', reason=NO_RAY)
  path, out, temp = _study(tmp_path, steps=4, every=2, one_cell=True), tmp_path / 'out', tempfile.mkdtemp(prefix='ray')
  host = socket.gethostname()
  slurm = {'SLURM_JOB_ID': '7', 'SLURM_JOB_NUM_NODES': '1', 'SLURM_NNODES': '1', 'SLURM_JOB_NODELIST': host,
           'SLURMD_NODENAME': host, 'SLURM_CPUS_ON_NODE': '2', 'SLURM_SUBMIT_DIR': str(REPO)}
  result = subprocess.run(['bash', str(REPO / 'tools' / 'slurm' / 'study_ray.sbatch'), str(path), '--out', str(out)],
                          cwd=tmp_path, env={**ENV, **slurm, 'FREENERF_VENV': sys.prefix, 'RAY_PORT': str(_free_port()),
                                             'RAY_TEMP_DIR': temp}, capture_output=True, text=True, timeout=600)
  assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
  assert 'Ray head on' in result.stdout and (out / 'mini' / 'results.csv').is_file()
  assert json.loads((out / 'mini' / 'freenerf__object' / 'cell.json').read_text())['step'] == 4
  assert _processes_mentioning(temp) == []                               # The cluster stopped with the script.
  shutil.rmtree(temp, ignore_errors=True)


@pytest.mark.parametrize('env, home_token, mode', [
    ({}, False, None), ({}, True, 'token'), ({'RAY_AUTH_TOKEN': 'x'}, False, 'token'),
    ({'RAY_AUTH_MODE': 'disabled'}, True, 'disabled')])
def test_a_driver_uses_token_authentication_where_ray_start_would(monkeypatch, tmp_path, env, home_token, mode):
  from tools.study import ray_executor as study_ray  # pylint: disable=import-outside-toplevel
  for name in ('RAY_AUTH_MODE', 'RAY_AUTH_TOKEN', 'RAY_AUTH_TOKEN_PATH'):
    monkeypatch.delenv(name, raising=False)
  monkeypatch.setenv('HOME', str(tmp_path))
  for name, value in env.items():
    monkeypatch.setenv(name, value)
  if home_token:
    (tmp_path / '.ray').mkdir()
    (tmp_path / '.ray' / 'auth_token').write_text('secret')
  study_ray._token_auth_if_token()  # pylint: disable=protected-access
  assert os.environ.get('RAY_AUTH_MODE') == mode


def test_resources_no_node_offers_are_an_error_here_and_a_warning_on_a_cluster(capsys):
  from tools.study import ray_executor as study_ray  # pylint: disable=import-outside-toplevel
  from tools.study import spec as study_spec  # pylint: disable=import-outside-toplevel
  nodes = [{'Alive': True, 'Resources': {'CPU': 8.}}, {'Alive': False, 'Resources': {'CPU': 8., 'GPU': 4.}}]
  study_ray.check_fits(study_spec.Resources(num_gpus=0, num_cpus=8), nodes, None)
  with pytest.raises(ValueError, match=r'asks for 1 GPU and 1 CPU .* \(nodes: 0 GPU and 8 CPU\); expected'):
    study_ray.check_fits(study_spec.Resources(num_gpus=1), nodes, None)   # The GPU node is dead.
  study_ray.check_fits(study_spec.Resources(num_gpus=1), nodes, '10.0.0.1:6379')
  assert 'warning: a cell asks for 1 GPU' in capsys.readouterr().err


@pytest.mark.parametrize('address, env, server', [('127.0.0.1:{port}', {}, None),
                                                 ('auto', {'RAY_ADDRESS': '127.0.0.1:{port}'}, None),
                                                 ('127.0.0.1:{port}', {}, http.server.HTTPServer)])
def test_an_address_where_no_cluster_answers_is_one_line_naming_it_within_seconds(tmp_path, address, env, server):
  """Nothing listens there (auto: as after `ray start` on a cluster that is gone), or a web server (the dashboard's
  port, say) does: Ray alone retries for many minutes."""
  pytest.importorskip('ray', reason=NO_RAY)
  port = _free_port()
  address, env = address.format(port=port), {k: v.format(port=port) for k, v in env.items()}
  web = server(('', port), http.server.SimpleHTTPRequestHandler) if server else None
  if web:
    threading.Thread(target=web.serve_forever, daemon=True).start()
  command = _study_command(_study(tmp_path), tmp_path / 'out', '--executor', 'ray', '--address', address)
  try:
    result = subprocess.run(command, cwd=REPO, env={**ENV, **env}, capture_output=True, text=True, timeout=120,
                            check=False)
  finally:
    if web:
      web.shutdown()
      web.server_close()
  why = ('is no Ray cluster (no gRPC answer within 10 s; is it the dashboard\'s port?)' if web else
         'within 10 s (Connection refused)')
  assert result.returncode == 2, result.stderr[-3000:]
  assert re.fullmatch(f'error: --address {re.escape(address)}: (nothing answers at|the server at) .*:{port}.* '
                      f'{re.escape(why)}; expected the address that `ray start --head` printed, e.g. '
                      '10.0.0.1:6379\n', result.stderr), result.stderr[-3000:]
  assert not (tmp_path / 'out').exists()


def test_ray_missing_is_one_line_naming_the_extra(capsys, monkeypatch, tmp_path):
  from internal import cli  # pylint: disable=import-outside-toplevel
  from tools.study import runner as study_lib  # pylint: disable=import-outside-toplevel
  monkeypatch.setitem(sys.modules, 'ray', None)  # As if not installed.
  path = _study(tmp_path)
  assert cli.run(lambda: study_lib.main([str(path), '--out', str(tmp_path), '--executor', 'ray'])) == 2
  assert capsys.readouterr().err == ('error: --executor ray needs Ray, which is not installed; expected the cluster '
                                     'extra: pip install -r requirements-cluster.txt\n')
