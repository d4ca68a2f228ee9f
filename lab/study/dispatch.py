"""Runs a study's cells on an executor (this machine's processes, or Ray: lab/study/ray_executor.py), each cell once over
every runner that shares the study folder, with a progress bar over the cells.

Each cell runs as its own process, `python -m lab.study --run-cell <cell dir> --job <job>`, whose output goes to
<cell>/log.txt; it claims the cell first (lab/study/claim.py) and exits with CLAIMED_STATUS when a runner of another
job holds it. Right before a cell is submitted the runner looks at it again: a finished cell (is_done) is counted,
a cell another runner holds is left for later and looked at every POLL_SECONDS (taken over if its claim goes
stale), so each command ends when every cell of its list has finished or failed.
"""

import concurrent.futures
import ctypes
import os
import queue
import signal
import socket
import subprocess
import sys
import time
import uuid
from typing import Callable, Dict, List, Optional, Tuple

import tqdm

from internal import progress
from lab.study import claim as study_claim
from lab.study import spec as study_spec

LOG_FILE = 'log.txt'
CLAIMED_STATUS = 75  # EX_TEMPFAIL: the cell is claimed by a runner of another job; look at it again later.
PARENT_ENV = 'FREENERF_STUDY_PARENT_PID'  # A cell process stops (checkpoint saved) when its runner dies.
POLL_SECONDS = 2.
PR_SET_PDEATHSIG = 1  # prctl(2) option: the signal a process gets when its parent dies.
REPO = study_spec.REPO


def new_job() -> str:
  """An id for one lab.study command: host, process id and a random part."""
  return f'{socket.gethostname()}-{os.getpid()}-{uuid.uuid4().hex[:8]}'


def python_path() -> str:
  """PYTHONPATH for a cell process: this repository first (lab.study is importable from any directory)."""
  return os.pathsep.join([REPO] + [p for p in [os.environ.get('PYTHONPATH')] if p])


def run_cell_process(path: str, job: str, env: Dict[str, str], cwd: Optional[str] = None,
                     children: Optional[set] = None) -> Tuple[int, float]:
  """Runs the cell of folder path in a fresh python process (output to <cell>/log.txt); (exit status, seconds).

  The process gets SIGINT (it saves a checkpoint and stops) if this one is interrupted; children, when given,
  holds it while it runs.
  """
  tic = time.perf_counter()
  with open(os.path.join(path, LOG_FILE), 'a') as log:
    child = subprocess.Popen([sys.executable, '-m', 'lab.study', '--run-cell', path, '--job', job], stdout=log,
                             stderr=subprocess.STDOUT, cwd=cwd,
                             env={**os.environ, 'PYTHONPATH': python_path(), PARENT_ENV: str(os.getpid()), **env})
  if children is not None:
    children.add(child)
  try:
    status = _wait(child)
  except KeyboardInterrupt:
    child.send_signal(signal.SIGINT)
    child.wait()
    raise
  finally:
    if children is not None:
      children.discard(child)
  return status, time.perf_counter() - tic


def _wait(child: subprocess.Popen) -> int:
  """The child's exit status, waited for in short sleeps (a KeyboardInterrupt that Ray raises on cancelling a
  task arrives between them, not after the child ends)."""
  while True:
    try:
      return child.wait(timeout=0.5)
    except subprocess.TimeoutExpired:
      pass


class LocalExecutor:
  """Cells as processes on this machine, one per worker at a time, each with its worker's environment (GPU)."""

  def __init__(self, envs: List[Dict[str, str]], job: str):
    self.slots, self.job, self.children = len(envs), job, set()
    self.free = queue.Queue()
    for env in envs:
      self.free.put(env)
    self.pool = concurrent.futures.ThreadPoolExecutor(len(envs))

  def submit(self, path: str) -> concurrent.futures.Future:
    return self.pool.submit(self._work, path)

  def _work(self, path: str) -> Tuple[int, float]:
    env = self.free.get()
    try:
      return run_cell_process(path, self.job, env, children=self.children)
    finally:
      self.free.put(env)

  def cancel(self, futures) -> None:
    """Stops the running cells (each saves a checkpoint) and drops the queued ones."""
    del futures
    for child in list(self.children):
      child.send_signal(signal.SIGINT)
    self.pool.shutdown(wait=True, cancel_futures=True)

  def close(self) -> None:
    self.pool.shutdown()


def _outcome(future: concurrent.futures.Future) -> Tuple[Optional[int], str]:
  """(exit status, '') of a finished cell's future, or (None, why) when its executor lost it for good."""
  try:
    status, _ = future.result()
  except Exception as e:  # pylint: disable=broad-except  (Ray's errors: a cell lost after its retries)
    return None, f'{type(e).__name__}: {str(e).strip().splitlines()[0] if str(e).strip() else ""}'
  return status, ''


def run(paths: List[str], executor, is_done: Callable[[str], bool]) -> Dict[str, str]:
  """Runs the cells of paths on executor (submit, cancel, slots); returns {path: error} of the failed cells."""
  pending, running, failed, shown = list(paths), {}, {}, time.monotonic()
  with tqdm.tqdm(total=len(paths), desc='cells', unit='cell', **progress.progress_kwargs()) as bar:
    try:
      while pending or running:
        _submit(pending, running, executor, is_done, bar)
        _collect(running, pending, failed, bar)
        bar.set_postfix_str(_states(running, pending, failed, is_done), refresh=False)
        if time.monotonic() - shown >= bar.mininterval:  # Elapsed time and states move while cells run.
          bar.refresh()
          shown = time.monotonic()
    except KeyboardInterrupt:
      executor.cancel(list(running))
      raise
  return failed


def _submit(pending: list, running: dict, executor, is_done: Callable[[str], bool], bar) -> None:
  """Counts the pending cells that finished meanwhile and submits those that no runner holds, while slots last."""
  for path in list(pending):
    if is_done(path):
      pending.remove(path)
      bar.update(1)
    elif len(running) < executor.slots and study_claim.live_holder(path) is None:
      pending.remove(path)
      tqdm.tqdm.write(f'running {path}', file=sys.stdout)
      running[executor.submit(path)] = path


def _states(running: dict, pending: list, failed: dict, is_done: Callable[[str], bool]) -> str:
  """'running R, queued Q, elsewhere E, failed F': cells working (claimed, or finished and ending), waiting for a
  worker or a slot, held by other runners, failed."""
  claimed = sum(study_claim.live_holder(p) is not None or is_done(p) for p in running.values())
  elsewhere = sum(study_claim.live_holder(p) is not None for p in pending)
  queued = len(running) - claimed + len(pending) - elsewhere
  return f'running {claimed}, queued {queued}, elsewhere {elsewhere}, failed {len(failed)}'


def _collect(running: dict, pending: list, failed: dict, bar) -> None:
  """Waits up to POLL_SECONDS for cells to end; moves each ended one to done, failed or (claimed) pending."""
  if not running:
    time.sleep(POLL_SECONDS)
    return
  ended, _ = concurrent.futures.wait(running, POLL_SECONDS, concurrent.futures.FIRST_COMPLETED)
  for future in ended:
    path = running.pop(future)
    status, error = _outcome(future)
    if status == 0:
      bar.update(1)
    elif status == CLAIMED_STATUS:
      pending.append(path)
    else:
      failed[path] = error or f'exit status {status}; see {os.path.join(path, LOG_FILE)}'


def stop_with_runner() -> None:
  """In a cell process: takes SIGINT and SIGTERM (a Ray worker starts it with them blocked) and, on Linux, gets
  SIGTERM (the training loop saves a checkpoint and stops) when the runner that started it dies, so that no cell
  trains on unattended."""
  signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
  parent = os.environ.get(PARENT_ENV)
  if not parent or not sys.platform.startswith('linux'):
    return
  ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
  if os.getppid() != int(parent):  # The runner died before the request.
    os.kill(os.getpid(), signal.SIGTERM)
