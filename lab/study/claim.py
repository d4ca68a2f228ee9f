"""Claims on a study's cells: one process at a time trains a cell, however many runners share the study folder.

Every runner (a `lab.study` process, a `--shard` of it on another host, a Ray task) runs a cell through the
same cell process, which claims the cell before any work: <cell>/claim.json appears atomically (written beside it,
then hard-linked into place, which fails when the file exists, on NFS too) holding the claimer's host, process id,
job (the `lab.study` command that started it) and start time. The holder touches the file every
HEARTBEAT_SECONDS while it works and removes it when it stops. With the claim taken it looks at the cell again: a
cell with cell.json is finished and is neither trained nor written again.

A claim is stale, and the next runner that finds it takes it over, when its process is gone (a holder on the same
host: checked at once), when its file has not been touched for STALE_SECONDS (any host: a node that died; the hosts'
clocks must agree within a minute, as NTP keeps them) or when its file holds no holder record (garbage: a claim
appears complete, so that is no live runner's; taken over at once). A runner takes a stale claim over under a
takeover lock (<cell>/claim.json.takeover, created like a claim): it removes the claim only if it is still the stale
one it saw, then claims the cell like any runner, so of several runners that find one claim stale a single one takes
it (a takeover lock older than TAKEOVER_STALE_SECONDS was left by a taker that died and is removed). A cell process
of the same job that finds a live claim waits for it (a retried Ray task whose first attempt is still saving its
checkpoint); one of another job stops with Held and its runner looks at the cell again later. A runner stopped by
Ctrl-C asks its cells' processes to stop through <cell>/claim.stop (they save a checkpoint and release their
claims), wherever they run.
"""

import contextlib
import json
import os
import signal
import socket
import threading
import time
import uuid
from typing import Iterator, Optional, Tuple

from internal import atomic
from internal import lock_holders

CLAIM_FILE = 'claim.json'
STOP_FILE = 'claim.stop'  # A runner's request that its job's cell process stop (its Ctrl-C, on any host).
HEARTBEAT_SECONDS = 30.
STALE_SECONDS = 300.
WAIT_POLL_SECONDS = 0.5  # How often a cell process of the holder's job looks at the claim again.
STOP_POLL_SECONDS = 1.  # How often a holder looks for a stop request.
TAKEOVER_POLL_SECONDS = 0.05  # How soon a runner that found another taking over a stale claim looks again.
TAKEOVER_STALE_SECONDS = 60.  # A takeover lock this old was left by a taker that died while holding it.


class Held(Exception):
  """The cell is claimed by a live runner of another job; the message names it."""


def claim_path(cell_path: str) -> str:
  return os.path.join(cell_path, CLAIM_FILE)


def _read(path: str) -> Tuple[Optional[dict], float]:
  """(record in the file, its mtime): (None, 0) when there is no file, ({}, mtime) when it holds no JSON object; a
  ValueError naming the file when it cannot be read."""
  try:
    mtime = os.stat(path).st_mtime
    with open(path, 'rb') as f:
      data = f.read()
  except FileNotFoundError:
    return None, 0.
  except OSError as e:
    raise ValueError(f'{path!r} cannot be read ({e.strerror}); expected a claim file (lab/study/claim.py) that '
                     'this user can read') from None
  try:
    holder = json.loads(data)
  except (UnicodeDecodeError, json.JSONDecodeError):
    return {}, mtime
  return (holder if isinstance(holder, dict) else {}), mtime


def is_stale(holder: dict, mtime: float, now: float) -> bool:
  """Whether a claim (its holder record and file mtime) may be taken over at time now: at once when the file holds
  no holder record (claims appear complete, so it is no live runner's)."""
  return 'token' not in holder or lock_holders.process_gone(holder) or now - mtime > STALE_SECONDS


def live_holder(cell_path: str) -> Optional[dict]:
  """The holder of the cell's claim while it is live; None when the cell is unclaimed or its claim is stale."""
  holder, mtime = _read(claim_path(cell_path))
  if holder is None or is_stale(holder, mtime, time.time()):
    return None
  return holder


def describe(holder: dict) -> str:
  """'process 12 on host 'a' (job j, since ...)' for messages."""
  if 'token' not in holder:
    return 'nobody (the file holds no claim)'
  return (f"process {holder.get('pid')} on host {holder.get('host')!r} (job {holder.get('job')}, since "
          f"{holder.get('started')})")


def _create(path: str, holder: dict) -> bool:
  """Creates the claim file holding holder, complete before it appears; False when one exists."""
  tmp = f"{path}.{holder['token']}.tmp"
  atomic.write_text(tmp, json.dumps(holder))
  try:
    os.link(tmp, path)
    return True
  except FileExistsError:
    return False
  finally:
    os.unlink(tmp)


def _take_over(path: str, seen: dict) -> None:
  """Removes the stale claim seen at path, under the takeover lock (<claim>.takeover), if it is still there."""
  lock = f'{path}.takeover'
  if not _create(lock, {'host': socket.gethostname(), 'pid': os.getpid(), 'token': uuid.uuid4().hex}):
    if time.time() - _read(lock)[1] > TAKEOVER_STALE_SECONDS:  # Its taker died within the few lines below.
      with contextlib.suppress(FileNotFoundError):
        os.remove(lock)
    time.sleep(TAKEOVER_POLL_SECONDS)
    return
  try:
    if _read(path)[0] == seen:  # Not yet replaced by a fresh claim (only a taker removes another's claim).
      os.remove(path)
      print(f'warning: took over the stale claim of {describe(seen)} in {path!r}', flush=True)
  finally:
    os.remove(lock)


def acquire(cell_path: str, job: str, wait: bool = False) -> dict:
  """Claims the cell in folder cell_path for job; returns the holder record. Held if a runner of another job
  holds it (with wait: waits for it); waits while one of the same job does."""
  path = claim_path(cell_path)
  holder = {'host': socket.gethostname(), 'pid': os.getpid(), 'job': job, 'token': uuid.uuid4().hex,
            'started': time.strftime('%Y-%m-%d %H:%M:%S %z')}
  while not _create(path, holder):
    current, mtime = _read(path)
    if current is None:
      continue
    if is_stale(current, mtime, time.time()):
      _take_over(path, current)
    elif wait or current.get('job') == job:
      time.sleep(WAIT_POLL_SECONDS)
    else:
      raise Held(f'{cell_path!r} is claimed by {describe(current)}')
  return holder


def release(cell_path: str, holder: dict) -> None:
  """Removes the claim if it is still this holder's."""
  path = claim_path(cell_path)
  if _read(path)[0] == holder:
    with contextlib.suppress(FileNotFoundError):
      os.remove(path)


def request_stop(cell_path: str, job: str) -> None:
  """Asks the cell process of job that holds the cell (on any host) to stop as on Ctrl-C (checkpoint saved)."""
  atomic.write_text(os.path.join(cell_path, STOP_FILE), json.dumps({'job': job}))


def _stop_requested(cell_path: str, holder: dict) -> bool:
  """Whether a stop request for the holder's job is there (then it is removed: it is answered once)."""
  path = os.path.join(cell_path, STOP_FILE)
  if (_read(path)[0] or {}).get('job') != holder['job']:
    return False
  with contextlib.suppress(FileNotFoundError):
    os.remove(path)
  return True


def _heartbeat(cell_path: str, holder: dict, stop: threading.Event) -> None:
  """Until stop is set: touches the claim file every HEARTBEAT_SECONDS while it is this holder's, and answers a
  stop request with SIGINT to this process (the training loop saves a checkpoint and stops)."""
  path, touched = claim_path(cell_path), time.monotonic()
  while not stop.wait(STOP_POLL_SECONDS):
    try:
      if _stop_requested(cell_path, holder):
        os.kill(os.getpid(), signal.SIGINT)
      if time.monotonic() - touched >= HEARTBEAT_SECONDS:
        if _read(path)[0] != holder:
          return
        with contextlib.suppress(FileNotFoundError):
          os.utime(path)
        touched = time.monotonic()
    except ValueError:  # A file that cannot be read just now: looked at again at the next poll.
      continue


@contextlib.contextmanager
def claimed(cell_path: str, job: str, wait: bool = False) -> Iterator[dict]:
  """Holds the claim of the folder cell_path (see acquire), touched by a heartbeat thread, until the block ends."""
  holder = acquire(cell_path, job, wait)
  stop = threading.Event()
  beat = threading.Thread(target=_heartbeat, args=(cell_path, holder, stop), daemon=True)
  beat.start()
  try:
    yield holder
  finally:
    stop.set()
    beat.join()
    release(cell_path, holder)
