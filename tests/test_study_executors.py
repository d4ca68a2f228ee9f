"""tools.study's executors on one tiny 4-cell study: one process, two processes sharing the folder, and Ray (a real
cluster started with `ray start --head`; skipped without the cluster extra); each cell trained once and the same
results.csv to the last digit (training is deterministic). Also a Ray worker killed mid-cell, then Ctrl-C."""

import csv
import json
import os
import pathlib
import signal
import socket
import subprocess
import sys
import tempfile
import time

import pytest

from conftest import JAX_CACHE
from tools import study_claim

REPO = pathlib.Path(__file__).resolve().parents[1]
STEPS = 12
STUDY = f'''
name = "tiny"
bindings = ["MLP.net_depth = 2", "MLP.net_width = 16", "MLP.net_width_viewdirs = 16",
            "MipNerfModel.num_samples = 8", "Config.batch_size = 64", "Config.max_steps = {{steps}}",
            "Config.freq_reg_end = 10", "Config.print_every = 100", "Config.train_render_every = 0",
            "Config.checkpoint_every = {{every}}", "Config.compute_lpips = False", "Config.render_chunk_size = 192",
            "Config.eval_test_ids = [0, 1]", "Config.generated_size = (12, 16)",
            "Config.data_dir = '{{{{out}}}}/scenes/{{{{scene}}}}'"]
[methods.freenerf]
configs = ["{REPO}/configs/demo.gin"]
[methods.mipnerf]
configs = ["{REPO}/configs/demo.gin"]
bindings = ["Config.freq_reg = False", "Config.freq_reg_end = 0", "Config.occ_reg_loss_mult = 0."]
[scenes.object]
bindings = ["Config.generated_rig = 'object'"]
[scenes.forward]
bindings = ["Config.generated_rig = 'forward'"]
'''
COMPARED = ('cell', 'method', 'scene', 'status', 'step', 'complete', 'psnr', 'ssim', 'depth_mae',
            'depth_within_1pct', 'depth_within_5pct', 'steps_trained')
ENV = {**os.environ, 'JAX_COMPILATION_CACHE_DIR': JAX_CACHE, 'JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS': '0'}


def _study(tmp_path, name='tiny.toml', steps=STEPS, every=6, methods=None):
  """A study file under tmp_path (with methods, only those) -> its path."""
  text = STUDY.format(steps=steps, every=every)
  if methods:
    text = text.split('[methods.freenerf]')[0] + f'[methods.{methods}]\nconfigs = ["{REPO}/configs/demo.gin"]\n' + (
        '[scenes.object]\nbindings = ["Config.generated_rig = \'object\'"]\n')
  path = tmp_path / name
  path.write_text(text)
  return path


def _study_command(path, out, *flags):
  return [sys.executable, '-m', 'tools.study', str(path), '--out', str(out), *flags]


def _results(out):
  with open(pathlib.Path(out) / 'tiny' / 'results.csv', newline='') as f:
    return [{k: row[k] for k in COMPARED} for row in csv.DictReader(f)]


def _trained_once(out):
  """Each cell's log holds exactly one cell record: no cell was trained (or written) twice."""
  for log in pathlib.Path(out, 'tiny').glob('*/log.txt'):
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


def test_two_processes_on_one_folder_train_each_cell_once(reference, tmp_path):
  path, rows = reference
  out = tmp_path / 'two'
  runners = [subprocess.Popen(_study_command(path, out), cwd=REPO, env=ENV, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True) for _ in range(2)]
  outputs = [r.communicate(timeout=600)[0] for r in runners]
  assert [r.returncode for r in runners] == [0, 0], outputs
  assert _results(out) == rows
  _trained_once(out)
  assert not list(out.glob(f'tiny/*/{study_claim.CLAIM_FILE}*'))             # Every claim released.


@pytest.fixture(scope='module', name='cluster')
def fixture_cluster():
  """The address of a local Ray cluster started as on a head node, `ray start --head`, in its own process."""
  pytest.importorskip('ray', reason='the cluster extra is not installed (pip install -r requirements-cluster.txt)')
  with socket.socket() as s:
    s.bind(('127.0.0.1', 0))
    port = s.getsockname()[1]
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


def test_ray_gives_the_local_executors_results(reference, cluster, tmp_path):
  path, rows = reference
  out = tmp_path / 'ray'
  result = subprocess.run(_study_command(path, out, '--executor', 'ray', '--address', cluster, '--num-cpus', '1'),
                          cwd=REPO, env=ENV, capture_output=True, text=True, timeout=600, check=False)
  assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
  assert _results(out) == rows
  _trained_once(out)
  assert 'cells: 100%' in result.stderr and 'failed 0' in result.stderr


def _wait_for(predicate, what, timeout=300.):
  deadline = time.time() + timeout
  while not predicate():
    assert time.time() < deadline, f'timed out waiting for {what}'
    time.sleep(0.2)


def _latest_step(run_dir):
  """The newest step folder of the run's checkpoints (orbax writes it under a temporary name first), or None."""
  folder = run_dir / 'checkpoints'
  return max((int(n) for n in os.listdir(folder) if n.isdigit()), default=None) if folder.is_dir() else None


def test_a_killed_worker_is_retried_from_its_checkpoint_and_ctrl_c_stops_cleanly(cluster, tmp_path):
  path = _study(tmp_path, steps=4000, every=200, methods='freenerf')
  out, cell = tmp_path / 'out', tmp_path / 'out' / 'tiny' / 'freenerf__object'
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
  driver.send_signal(signal.SIGINT)                                 # Ctrl-C: the cell stops, its checkpoint saved.
  output = driver.communicate(timeout=300)[0]
  assert driver.returncode == 128 + signal.SIGINT and 'interrupted:' in output, output[-3000:]
  assert not (cell / study_claim.CLAIM_FILE).exists() and not (cell / 'cell.json').exists()
  stopped_at = _latest_step(cell / 'run')
  rerun = subprocess.run(command, cwd=REPO, env=ENV, capture_output=True, text=True, timeout=600, check=False)
  assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
  record = json.loads((cell / 'cell.json').read_text())
  assert record['step'] == 4000 and record['steps_trained'] == 4000 - stopped_at
  assert record['resumed_from_step'] == stopped_at > killed_at, (record['resumed_from_step'], stopped_at, killed_at)
