"""dispatch.run (lab/study/dispatch.py) with a stand-in executor: finished cells counted, cells held by another runner waited for
(not submitted), a cell whose process lost the claim race looked at again, failures reported, Ctrl-C cancels."""

import concurrent.futures
import json
import os
import socket
import threading

import pytest

from lab.study import claim as study_claim
from lab.study import dispatch


class FakeExecutor:
  """Answers each submitted cell with the next status of its script; records the submissions."""
  slots = 2

  def __init__(self, scripts):
    self.scripts, self.submitted, self.cancelled = scripts, [], None

  def submit(self, path):
    self.submitted.append(os.path.basename(path))
    status = self.scripts[os.path.basename(path)].pop(0)
    future = concurrent.futures.Future()
    if isinstance(status, BaseException):
      future.set_exception(status)
    else:
      if status == 0:
        open(os.path.join(path, 'cell.json'), 'w').close()
      future.set_result((status, 0.))
    return future

  def cancel(self, futures):
    self.cancelled = futures


def _cells(tmp_path, names):
  for name in names:
    (tmp_path / name).mkdir()
  return [str(tmp_path / n) for n in names]


def _done(path):
  return os.path.isfile(os.path.join(path, 'cell.json'))


def test_cells_run_once_each_and_failures_are_reported(tmp_path, monkeypatch):
  monkeypatch.setattr(dispatch, 'POLL_SECONDS', 0.01)
  paths = _cells(tmp_path, ['done', 'ok', 'raced', 'bad', 'lost', 'held'])
  open(os.path.join(paths[0], 'cell.json'), 'w').close()
  (tmp_path / 'held' / study_claim.CLAIM_FILE).write_text(json.dumps(
      {'host': socket.gethostname(), 'pid': os.getpid(), 'job': 'another', 'token': 't'}))
  threading.Timer(0.3, lambda: open(os.path.join(paths[5], 'cell.json'), 'w').close()).start()  # Finished there.
  executor = FakeExecutor({'ok': [0], 'raced': [dispatch.CLAIMED_STATUS, 0], 'bad': [1],
                           'lost': [RuntimeError('WorkerCrashedError after 3 retries\nmore')]})
  failed = dispatch.run(paths, executor, _done)
  assert sorted(executor.submitted) == ['bad', 'lost', 'ok', 'raced', 'raced']
  assert failed == {paths[3]: f'exit status 1; see {os.path.join(paths[3], "log.txt")}',
                    paths[4]: 'RuntimeError: WorkerCrashedError after 3 retries'}


def test_ctrl_c_cancels_what_runs_and_stops(tmp_path, monkeypatch):
  paths = _cells(tmp_path, ['a', 'b'])

  class Hanging(FakeExecutor):
    def submit(self, path):
      self.submitted.append(path)
      return concurrent.futures.Future()  # Never ends.

  executor = Hanging({})

  def interrupt(*_):
    raise KeyboardInterrupt

  monkeypatch.setattr(dispatch, '_collect', interrupt)
  with pytest.raises(KeyboardInterrupt):
    dispatch.run(paths, executor, _done)
  assert len(executor.cancelled) == 2 and executor.submitted == paths
