"""Several cooperating processes on JAX's multi-controller runtime (jax.distributed), one per host or GPU group.

Every process runs the same program: the step's global batch is split over all devices of all processes, the
parameters are replicated. Process 0 (the primary) alone takes the run lock and writes the run's metadata, logs
and progress; orbax coordinates the checkpoint writes of all processes. With one process every function here
does what a plain single-process program would.
"""

import argparse
import os

import jax
import numpy as np
from jax.experimental import multihost_utils

# Flags of train.py and the environment variables that give their defaults.
ENV = {'coordinator_address': 'JAX_COORDINATOR_ADDRESS', 'num_processes': 'JAX_NUM_PROCESSES',
       'process_id': 'JAX_PROCESS_ID'}
INIT_TIMEOUT_S = 300  # How long a process waits for the others to join (jax's default).


class PrimaryFailed(RuntimeError):
  """Process 0 failed at a step the others wait for; its own error is printed by process 0."""


def add_flags(parser: argparse.ArgumentParser) -> None:
  """Adds --coordinator_address, --num_processes and --process_id (defaults: the JAX_* environment variables)."""
  group = parser.add_argument_group('several processes (jax.distributed); see README "Several GPUs and hosts"')
  group.add_argument('--coordinator_address', default=os.environ.get(ENV['coordinator_address'], ''),
                     metavar='HOST:PORT', help='address of process 0, the same for every process')
  group.add_argument('--num_processes', type=int, default=int(os.environ.get(ENV['num_processes'], '1')),
                     help='number of cooperating processes (default 1: no jax.distributed)')
  group.add_argument('--process_id', type=int, default=int(os.environ.get(ENV['process_id'], '0')),
                     help='this process, 0 .. num_processes - 1; process 0 writes logs and metadata')


def check_flags(args: argparse.Namespace) -> None:
  """Raises ValueError naming the flag when the process settings are inconsistent."""
  if args.num_processes < 1:
    raise ValueError(f'--num_processes = {args.num_processes} must be >= 1')
  if not 0 <= args.process_id < args.num_processes:
    raise ValueError(f'--process_id = {args.process_id} must be in 0 .. {args.num_processes - 1} '
                     f'(--num_processes = {args.num_processes})')
  if args.num_processes > 1 and ':' not in args.coordinator_address:
    raise ValueError(f'--coordinator_address = {args.coordinator_address!r} must be HOST:PORT of process 0 '
                     f'when --num_processes = {args.num_processes} (or set {ENV["coordinator_address"]})')


def initialize(args: argparse.Namespace) -> None:
  """Joins the jax.distributed job of the flags (nothing with one process); call it before any other jax call."""
  check_flags(args)
  if args.num_processes == 1:
    return
  jax.config.update('jax_cpu_collectives_implementation', 'gloo')  # CPU collectives across processes.
  jax.distributed.initialize(args.coordinator_address, num_processes=args.num_processes,
                             process_id=args.process_id, initialization_timeout=INIT_TIMEOUT_S)


def is_primary() -> bool:
  """True in process 0, the one that writes logs, metadata and progress."""
  return jax.process_index() == 0


def on_primary(fn, what: str):
  """fn() on process 0 only (None elsewhere), the others waiting; if it raised, they raise PrimaryFailed."""
  result, error = None, None
  if is_primary():
    try:
      result = fn()
    except Exception as e:  # pylint: disable=broad-except  (re-raised below, after telling the others)
      error = e
  if jax.process_count() > 1:
    failed = int(multihost_utils.broadcast_one_to_all(np.int32(error is not None)))
    if failed and error is None:
      raise PrimaryFailed(f'process 0 failed while {what} (its output says why)')
  if error is not None:
    raise error
  return result


def primary_first(fn, what: str):
  """fn() on process 0, then on the others (e.g. a load that may write a cache); returns fn's result."""
  result = on_primary(fn, what)
  return result if is_primary() else fn()


def max_over_processes(value: int) -> int:
  """The largest of an integer given by every process (the value itself with one process)."""
  if jax.process_count() == 1:
    return value
  return int(np.max(multihost_utils.process_allgather(np.int32(value))))
