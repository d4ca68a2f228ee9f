"""Cell claims (tools/study/claim.py): atomic, exclusive across processes, stale ones taken over by the documented rule,
and a finished cell never trained or written again."""

import json
import os
import socket
import subprocess
import sys
import threading
import time

import pytest

from tools.study import runner as study_lib
from tools.study import claim as study_claim

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _write_claim(cell, **holder):
  cell.mkdir(parents=True, exist_ok=True)
  path = cell / study_claim.CLAIM_FILE
  path.write_text(json.dumps({'host': socket.gethostname(), 'pid': os.getpid(), 'job': 'other', 'token': 't',
                              'started': 'then', **holder}))
  return path


def _dead_pid() -> int:
  child = subprocess.Popen([sys.executable, '-c', 'pass'])
  child.wait()
  return child.pid


def test_a_claim_is_exclusive_and_names_its_holder(tmp_path):
  holder = study_claim.acquire(str(tmp_path), 'job-a')
  recorded = json.loads((tmp_path / study_claim.CLAIM_FILE).read_text())
  assert recorded == holder and recorded['pid'] == os.getpid() and recorded['host'] == socket.gethostname()
  with pytest.raises(study_claim.Held, match=rf"process {os.getpid()} on host .* \(job job-a, since"):
    study_claim.acquire(str(tmp_path), 'job-b')
  assert study_claim.live_holder(str(tmp_path)) == holder
  study_claim.release(str(tmp_path), holder)
  assert not (tmp_path / study_claim.CLAIM_FILE).exists() and study_claim.live_holder(str(tmp_path)) is None
  study_claim.release(str(tmp_path), study_claim.acquire(str(tmp_path), 'job-b'))


def test_the_claim_of_a_dead_process_on_this_host_is_taken_over(tmp_path, capsys):
  _write_claim(tmp_path, pid=_dead_pid())
  assert study_claim.live_holder(str(tmp_path)) is None
  holder = study_claim.acquire(str(tmp_path), 'job-b')
  assert json.loads((tmp_path / study_claim.CLAIM_FILE).read_text())['job'] == 'job-b' == holder['job']
  assert 'took over the stale claim of process' in capsys.readouterr().out
  assert os.listdir(tmp_path) == [study_claim.CLAIM_FILE]  # Nothing of the takeover is left behind.


def test_another_hosts_claim_is_stale_only_when_its_heartbeat_stopped(tmp_path):
  path = _write_claim(tmp_path, host='another-node', pid=1)
  recent = time.time() - study_claim.STALE_SECONDS + 60
  os.utime(path, (recent, recent))
  with pytest.raises(study_claim.Held, match="host 'another-node'"):
    study_claim.acquire(str(tmp_path), 'job-b')
  old = time.time() - study_claim.STALE_SECONDS - 1
  os.utime(path, (old, old))
  assert study_claim.acquire(str(tmp_path), 'job-b')['job'] == 'job-b'


def test_the_heartbeat_keeps_the_claim_fresh_and_the_block_releases_it(tmp_path, monkeypatch):
  monkeypatch.setattr(study_claim, 'HEARTBEAT_SECONDS', 0.05)
  monkeypatch.setattr(study_claim, 'STOP_POLL_SECONDS', 0.02)
  with study_claim.claimed(str(tmp_path), 'job-a'):
    old = time.time() - 1000
    os.utime(tmp_path / study_claim.CLAIM_FILE, (old, old))
    time.sleep(0.3)
    assert time.time() - os.stat(tmp_path / study_claim.CLAIM_FILE).st_mtime < 5
  assert not (tmp_path / study_claim.CLAIM_FILE).exists()


def test_the_same_job_waits_for_its_earlier_attempt(tmp_path):
  """A retried Ray task finds its first attempt's claim while that process still saves its checkpoint."""
  first = study_claim.acquire(str(tmp_path), 'job-a')
  threading.Timer(0.5, study_claim.release, (str(tmp_path), first)).start()
  tic = time.perf_counter()
  second = study_claim.acquire(str(tmp_path), 'job-a')
  assert time.perf_counter() - tic >= 0.4 and second['token'] != first['token']


RACER = """
import sys, time
from tools.study import claim as study_claim
cell, job, start, done = sys.argv[1:]
judge = study_claim.is_stale
def slow_judge(*args):  # Every racer judges the claim stale before any takes it over, then acts in turn.
  stale = judge(*args)
  time.sleep(0.5 + 0.1 * int(job.split('-')[1]) if stale else 0.)
  return stale
study_claim.is_stale = slow_judge
while time.time() < float(start):
  time.sleep(0.001)
try:
  holder = study_claim.acquire(cell, job)
except study_claim.Held:
  print('held')
  sys.exit()
print('won', flush=True)
while len(open(done).read().split()) < 5:  # Held until every other racer has tried.
  time.sleep(0.01)
study_claim.release(cell, holder)
"""


def test_of_many_processes_that_find_a_stale_claim_one_takes_it(tmp_path):
  cell, done = tmp_path / 'cell', tmp_path / 'tried'
  _write_claim(cell, pid=_dead_pid())
  done.write_text('')
  start = str(time.time() + 2.)
  racers = [subprocess.Popen([sys.executable, '-c', RACER, str(cell), f'job-{i}', start, str(done)], cwd=REPO,
                             stdout=subprocess.PIPE, text=True) for i in range(6)]
  outcomes = []
  for racer in sorted(racers, key=lambda r: r.pid):
    line = racer.stdout.readline().strip()
    while line.startswith('warning: took over'):  # The taker's message, before its outcome.
      line = racer.stdout.readline().strip()
    outcomes.append(line)
    if line == 'held':
      with open(done, 'a') as f:
        f.write('x\n')
  for racer in racers:
    racer.wait(30)
  assert sorted(outcomes) == ['held'] * 5 + ['won']


def test_a_finished_cell_is_neither_run_nor_written_again(tmp_path):
  (tmp_path / study_lib.CELL_FILE).write_text('{"means": {"psnr": 10.5}}')
  before = (tmp_path / study_lib.CELL_FILE).read_text()
  assert study_lib.run_cell(str(tmp_path), 'job-a') is None        # Claimed, looked at again, not trained.
  with pytest.raises(FileExistsError):
    study_lib._publish(str(tmp_path), {'means': {'psnr': 1.}})  # pylint: disable=protected-access
  assert (tmp_path / study_lib.CELL_FILE).read_text() == before
  assert sorted(os.listdir(tmp_path)) == [study_lib.CELL_FILE]


def test_a_malformed_cell_json_is_one_error_naming_the_file(tmp_path):
  (tmp_path / study_lib.CELL_FILE).write_text('<<<<<<< HEAD\n{"means": {}}\n=======\n')
  with pytest.raises(ValueError, match=rf'{tmp_path / study_lib.CELL_FILE}: not valid JSON'):
    study_lib.read_cell(str(tmp_path))
