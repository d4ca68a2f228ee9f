"""Cells as Ray tasks (`python -m tools.study STUDY --executor ray [--address ADDRESS]`, docs/cluster.md).

Each cell becomes a task asking for the cell's resources (study_spec.Resources: num_gpus, num_cpus, max_retries)
that runs the cell process the local executor runs, in the driver's working directory: the study folder, the
repository and the data must be at the same paths on every node (a shared file system). Ray gives a task its GPUs
through CUDA_VISIBLE_DEVICES, which the cell process inherits. A task whose worker or node dies is retried up to
max_retries times; the cell's process dies with its worker (after saving a checkpoint where it can), and the retry
resumes from the cell's newest checkpoint. Without an address, a local Ray cluster is started on this machine and
stopped at the end. Ray is an optional extra: requirements-cluster.txt.
"""

import contextlib
import logging
import os
import signal
import socket
import sys

from tools.study import claim as study_claim
from tools.study import dispatch
from tools.study import spec as study_spec

CANCEL_WAIT_SECONDS = 120.  # Ctrl-C: how long the cancelled cells get to save a checkpoint and stop.
# --address: how long the cluster's port gets to answer. Ray itself retries a silent address, or one where another
# server answers, for many minutes.
CONNECT_SECONDS = 10.
# A cluster's address is its GCS, a gRPC server: it answers HTTP/2's client preface with a SETTINGS frame (type 4).
HTTP2_PREFACE = b'PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n' + bytes(3) + b'\x04' + bytes(5)  # + an empty SETTINGS frame


def _cell_task(path: str, job: str, cwd: str):
  """The Ray task: runs the cell's process in the driver's working directory; (exit status, seconds)."""
  return dispatch.run_cell_process(path, job, {}, cwd=cwd)


def _token_auth_if_token() -> None:
  """RAY_AUTH_MODE=token when it is unset and a token is there (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or
  ~/.ray/auth_token), as `ray start` decides: a driver must use the mode its cluster uses."""
  token_files = [os.environ.get('RAY_AUTH_TOKEN_PATH'), os.path.expanduser(os.path.join('~', '.ray', 'auth_token'))]
  if 'RAY_AUTH_MODE' not in os.environ and (os.environ.get('RAY_AUTH_TOKEN') or any(
      f and os.path.isfile(f) for f in token_files)):
    os.environ['RAY_AUTH_MODE'] = 'token'


def _import_ray():
  try:
    import ray  # pylint: disable=import-outside-toplevel  (an optional extra)
  except ImportError:
    raise ValueError('--executor ray needs Ray, which is not installed; expected the cluster extra: pip install '
                     '-r requirements-cluster.txt') from None
  return ray


def _resolved(ray, address: str) -> str:
  """The host:port that ray.init(address) connects to: 'auto' is the cluster Ray finds on this machine
  (RAY_ADDRESS, the last `ray start`); ValueError naming --address when it finds none."""
  try:
    from ray._private import services  # pylint: disable=import-outside-toplevel  (Ray's own resolution)
  except ImportError:
    return address
  try:
    return services.canonicalize_bootstrap_address(address) or address
  except ConnectionError as e:
    raise ValueError(f'--address {address}: no Ray cluster answered ({e}); expected the address that `ray start '
                     '--head` printed, e.g. 10.0.0.1:6379') from None


def check_answers(address: str, resolved: str, seconds: float = CONNECT_SECONDS) -> None:
  """ValueError naming --address unless a gRPC server (as a cluster's GCS) answers at resolved (host:port) within
  seconds (with TLS, RAY_USE_TLS: any server)."""
  host, _, port = resolved.rpartition(':')
  if not port.isdigit() or '://' in resolved:  # A Ray Client address (ray://...): ray.init reaches it itself.
    return
  where = resolved if resolved == address else f'{resolved} (where Ray looks for {address})'
  expected = 'expected the address that `ray start --head` printed, e.g. 10.0.0.1:6379'
  try:
    with socket.create_connection((host.strip('[]'), int(port)), timeout=seconds) as connection:
      if os.environ.get('RAY_USE_TLS', '0') not in ('', '0'):
        return
      connection.sendall(HTTP2_PREFACE)
      answer = connection.recv(9)
  except socket.timeout:
    answer = b''
  except OSError as e:
    raise ValueError(f'--address {address}: nothing answers at {where} within {seconds:g} s ({e.strerror or e}); '
                     f'{expected}') from None
  if len(answer) < 4 or answer[3] != 4:
    raise ValueError(f'--address {address}: the server at {where} is no Ray cluster (no gRPC answer within '
                     f'{seconds:g} s; is it the dashboard\'s port?); {expected}')


def _node_fits(resources: study_spec.Resources, node: dict) -> bool:
  return node.get('GPU', 0) >= resources.num_gpus and node.get('CPU', 0) >= resources.num_cpus


def check_fits(resources: study_spec.Resources, nodes: list, address) -> None:
  """ValueError (no address: a local cluster) or a warning (a cluster that may grow) when no node offers what a
  cell asks."""
  alive = [n['Resources'] for n in nodes if n.get('Alive')]
  if any(_node_fits(resources, n) for n in alive):
    return
  offers = ', '.join(sorted({f"{n.get('GPU', 0):g} GPU and {n.get('CPU', 0):g} CPU" for n in alive})) or 'none'
  message = (f'a cell asks for {resources.num_gpus:g} GPU and {resources.num_cpus:g} CPU (the study file\'s '
             f'[resources] or --num-gpus / --num-cpus), but no node of the Ray cluster offers that (nodes: {offers})')
  if address is None:
    raise ValueError(message + '; expected resources that this machine has')
  print(f'warning: {message}; the cells wait until such a node joins (Ctrl-C stops)', file=sys.stderr, flush=True)


def _still_stopping(signum, frame) -> None:
  """The driver's SIGINT and SIGTERM handler once it stops: says so instead of leaving before its cells (or Ray) are
  done."""
  del signum, frame
  print(f'still stopping: the cells save their checkpoints and end (up to {CANCEL_WAIT_SECONDS:g} s), then the '
        'driver leaves Ray', file=sys.stderr, flush=True)


class RayExecutor:
  """Submits cells as Ray tasks with the given resources; every cell is submitted at once (Ray queues them)."""
  slots = sys.maxsize

  def __init__(self, address, resources: study_spec.Resources, job: str):
    self.ray, self.job, self.submitted = _import_ray(), job, {}
    if address is not None:
      _token_auth_if_token()
      check_answers(address, _resolved(self.ray, address))
    try:
      self.ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False,
                    runtime_env={'env_vars': {'PYTHONPATH': dispatch.python_path()}})
    except ConnectionError as e:
      raise ValueError(f'--address {address}: no Ray cluster answered ({e}); expected the address that `ray start '
                       '--head` printed, e.g. 10.0.0.1:6379') from None
    check_fits(resources, self.ray.nodes(), address)
    self.task = self.ray.remote(_cell_task).options(num_gpus=resources.num_gpus, num_cpus=resources.num_cpus,
                                                    max_retries=resources.max_retries)

  def submit(self, path: str):
    ref = self.task.remote(path, self.job, os.getcwd())
    future = ref.future()
    self.submitted[future] = (ref, path)
    return future

  def cancel(self, futures) -> None:
    """Cancels the cells, each asked once: a running one (its claim held for this job) through its stop request,
    wherever it runs (it saves a checkpoint, releases its claim and exits, and its task ends); the others through
    Ray (a queued one never starts, a starting one gets SIGINT from its task). The tasks are waited for, up to
    CANCEL_WAIT_SECONDS; tasks still running then are ended. Called as the driver stops, it leaves further Ctrl-C
    and SIGTERM only reported from then on: a driver that left would take its tasks' processes down with it, in the
    middle of their checkpoints."""
    for signum in (signal.SIGINT, signal.SIGTERM):
      signal.signal(signum, _still_stopping)
    cancelled = [self.submitted[f] for f in futures]
    for ref, path in cancelled:
      if (study_claim.live_holder(path) or {}).get('job') == self.job:
        study_claim.request_stop(path, self.job)
      else:
        self.ray.cancel(ref)
    refs = [ref for ref, _ in cancelled]
    _, running = self.ray.wait(refs, num_returns=len(refs), timeout=CANCEL_WAIT_SECONDS) if refs else ([], [])
    for ref in running:
      self.ray.cancel(ref, force=True)
    for _, path in cancelled:
      with contextlib.suppress(FileNotFoundError):
        os.remove(os.path.join(path, study_claim.STOP_FILE))

  def close(self) -> None:
    self.ray.shutdown()
