"""Cell claims (lab/study/claim.py): atomic, exclusive across processes, stale ones taken over by the documented rule,
and a finished cell never trained or written again."""

import json
import os
import re
import socket
import subprocess
import sys
import threading
import time

import pytest

from lab.study import runner as study_lib
from lab.study import claim as study_claim

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


@pytest.mark.parametrize('garbage', [b'\x00\xff\x13garbage', b'{"host": "a", "pi', b'[1, 2]', b'{}'])
def test_a_claim_file_that_holds_no_claim_is_taken_over_at_once_naming_it(tmp_path, capsys, garbage):
  """Claims appear whole (written beside, then linked), so a file that holds no holder record is no live runner's."""
  (tmp_path / study_claim.CLAIM_FILE).write_bytes(garbage)
  assert study_claim.live_holder(str(tmp_path)) is None  # The runner submits the cell at once.
  tic = time.perf_counter()
  holder = study_claim.acquire(str(tmp_path), 'job-b')
  assert time.perf_counter() - tic < 1. and json.loads((tmp_path / study_claim.CLAIM_FILE).read_text()) == holder
  assert capsys.readouterr().out == (f'warning: took over the stale claim of nobody (the file holds no claim) in '
                                     f'{str(tmp_path / study_claim.CLAIM_FILE)!r}\n')


def test_a_claim_file_that_cannot_be_read_is_one_error_naming_it(tmp_path):
  (tmp_path / study_claim.CLAIM_FILE).mkdir()  # Reading it fails whatever this user may read.
  with pytest.raises(ValueError, match=f"^{re.escape(repr(str(tmp_path / study_claim.CLAIM_FILE)))} cannot be read"):
    study_claim.live_holder(str(tmp_path))


# A racer: claims the cell; at its first write into the cell (a claim or a takeover lock being created) it waits
# until every racer is there, so all of them act on what they found at once (a claim made by a check, then a write,
# would let several through); a winner holds its claim until every racer has an outcome.
RACER = """
import os, sys, time
from lab.study import claim as study_claim
cell, job, arrived, tried, racers = sys.argv[1:]
racers, pending, deadline = int(racers), [True], time.time() + 60.
WRITES = os.O_WRONLY | os.O_RDWR | os.O_CREAT

def count(path):
  return len(open(path).read().split())

def barrier(event, args):
  writes = event == 'open' and args[2] is not None and args[2] & WRITES or event in ('os.link', 'os.rename')
  if pending[0] and writes and os.fspath(args[1] if event == 'os.link' else args[0]).startswith(cell):
    pending[0] = False
    with open(arrived, 'a') as f:
      f.write(job + ' ')
    while count(arrived) < racers and time.time() < deadline:
      time.sleep(0.001)

sys.addaudithook(barrier)
try:
  holder, outcome = study_claim.acquire(cell, job), 'won'
except study_claim.Held:
  outcome = 'held'
print(outcome, flush=True)
with open(tried, 'a') as f:
  f.write(outcome + ' ')
while count(tried) < racers and time.time() < deadline:
  time.sleep(0.01)
if outcome == 'won':
  study_claim.release(cell, holder)
"""


@pytest.mark.parametrize('stale', [False, True])
def test_of_many_processes_that_race_for_a_cell_one_claims_it(tmp_path, stale):
  """Six racers at once on a free cell, or on a cell whose claim is stale (each judges it stale, then all race
  for the takeover)."""
  cell, arrived, tried = tmp_path / 'cell', tmp_path / 'arrived', tmp_path / 'tried'
  cell.mkdir()
  if stale:
    _write_claim(cell, pid=_dead_pid())
  arrived.write_text('')
  tried.write_text('')
  racers = [subprocess.Popen([sys.executable, '-c', RACER, str(cell), f'job-{i}', str(arrived), str(tried), '6'],
                             cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            for i in range(6)]
  outputs = [racer.communicate(timeout=120)[0] for racer in racers]
  assert len(arrived.read_text().split()) == 6, outputs  # Every racer waited at the barrier.
  outcomes = [line for output in outputs for line in output.splitlines() if not line.startswith('warning: took')]
  assert sorted(outcomes) == ['held'] * 5 + ['won'], outputs
  assert os.listdir(cell) == []  # The winner released its claim; nothing of the takeover is left behind.


def test_a_finished_cell_is_neither_run_nor_written_again(tmp_path):
  (tmp_path / study_lib.CELL_FILE).write_text('{"step": 100, "means": {"psnr": 10.5}}')
  before = (tmp_path / study_lib.CELL_FILE).read_text()
  assert study_lib.run_cell(str(tmp_path), 'job-a') is None        # Claimed, looked at again, not trained.
  with pytest.raises(FileExistsError):
    study_lib._publish(str(tmp_path), {'means': {'psnr': 1.}})  # pylint: disable=protected-access
  assert (tmp_path / study_lib.CELL_FILE).read_text() == before
  assert sorted(os.listdir(tmp_path)) == [study_lib.CELL_FILE]


def test_a_cell_json_without_its_step_is_one_error_naming_the_file(tmp_path):
  (tmp_path / study_lib.CELL_FILE).write_text('{"means": {"psnr": 10.5}}')
  with pytest.raises(ValueError, match=rf'{tmp_path / study_lib.CELL_FILE}: .*final step'):
    study_lib.read_cell(str(tmp_path))


def test_a_malformed_cell_json_is_one_error_naming_the_file(tmp_path):
  (tmp_path / study_lib.CELL_FILE).write_text('<<<<<<< HEAD\n{"means": {}}\n=======\n')
  with pytest.raises(ValueError, match=rf'{tmp_path / study_lib.CELL_FILE}: not valid JSON'):
    study_lib.read_cell(str(tmp_path))
