"""Training as 2 cooperating processes (jax.distributed, gloo on 127.0.0.1, 1 CPU device each) equals 1 process."""

import argparse
import glob
import os
import signal
import socket
import struct
import subprocess
import sys
import time

import jax
import numpy as np
import pytest
from tensorboardX.proto import event_pb2

from internal import datasets
from internal.evaluation import learning_curve
from internal.run import checkpoints
from internal.run import distributed
from internal.pipeline import loop
from internal.run import run_dir as run_dir_lib
from conftest import JAX_CACHE
from test_checkpoints import DEMO, ROOT, TINY, _leaves, tiny_config

STEPS = 8
BINDINGS = (f'Config.max_steps = {STEPS}', 'Config.checkpoint_every = 2', 'Config.print_every = 1')
TIMEOUT_S = 480  # For each launch of the 2 processes (startup and compiles take minutes on a busy 2-core CPU).
TOLERANCE = 1e-5


def _free_port() -> int:
  """A TCP port of 127.0.0.1 that nothing listens on now."""
  with socket.socket() as s:
    s.bind(('127.0.0.1', 0))
    return s.getsockname()[1]


def _launch(scene_dir, run) -> list:
  """Starts the 2 processes of one training of run; returns their Popen objects."""
  port = _free_port()
  bindings = TINY + [f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'", *BINDINGS]
  env = dict(os.environ, JAX_PLATFORMS='cpu', XLA_FLAGS='--xla_force_host_platform_device_count=1',
             JAX_COORDINATOR_BIND_ADDRESS=f'127.0.0.1:{port}', JAX_COMPILATION_CACHE_DIR=JAX_CACHE,
             JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0')
  return [subprocess.Popen([sys.executable, 'train.py', '--gin_configs', DEMO, '--gin_bindings', *bindings,
                            '--coordinator_address', f'127.0.0.1:{port}', '--num_processes', '2',
                            '--process_id', str(i)],
                           cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
          for i in range(2)]


def _finish(procs) -> None:
  """Waits for both processes (killing them past TIMEOUT_S); asserts that both exited with status 0."""
  deadline = time.time() + TIMEOUT_S
  outputs = []
  for proc in procs:
    try:
      outputs.append(proc.communicate(timeout=max(deadline - time.time(), 1))[0])
    except subprocess.TimeoutExpired:
      for p in procs:
        p.kill()
      pytest.fail(f'2-process training did not finish within {TIMEOUT_S} s')
  for i, (proc, out) in enumerate(zip(procs, outputs)):
    assert proc.returncode == 0, f'process {i}:\n{out[-3000:]}'


def _losses(run) -> dict:
  """{step: train/loss} from the tensorboard event files of run (the last value logged for each step)."""
  losses = {}
  for path in sorted(glob.glob(str(run / 'tensorboard' / 'events.*'))):
    data = open(path, 'rb').read()
    offset = 0
    while offset + 12 <= len(data):  # TFRecord: u64 length, u32 crc, payload, u32 crc.
      (length,) = struct.unpack('<Q', data[offset:offset + 8])
      event = event_pb2.Event.FromString(data[offset + 12:offset + 12 + length])
      offset += 16 + length
      for value in event.summary.value:
        if value.tag == 'train/loss':
          losses[event.step] = value.simple_value
  return losses


def _state(scene_dir, run):
  """The newest TrainState of run, restored in this (single) process."""
  config = tiny_config(scene_dir, run, *BINDINGS)
  rays = jax.tree.map(lambda x: x[0, 0, :8], datasets.load_dataset('train', config).rays)
  return checkpoints.restore_model(config, str(run), rays)[1]


@pytest.fixture(scope='module')
def one_process(tmp_path_factory, scene_dir):
  """(final TrainState, losses, learning-curve rows) of the run trained by this process alone (it writes the scene)."""
  run = tmp_path_factory.mktemp('one') / 'run'
  state = loop.train(tiny_config(scene_dir, run, *BINDINGS)).state
  return jax.device_get(state), _losses(run), learning_curve.read_rows(learning_curve.csv_path(run))


def _assert_close(state, losses, reference, first_logged: int = 1) -> None:
  """Parameters, optimizer state and the losses of steps first_logged.. equal the reference's within TOLERANCE."""
  ref_state, ref_losses, _ = reference
  assert int(state.step) == int(ref_state.step) == STEPS
  diff = max(float(np.max(np.abs(a - b))) for a, b in zip(_leaves(state), _leaves(ref_state)))
  assert diff < TOLERANCE, diff
  assert sorted(ref_losses) == list(range(1, STEPS + 1))
  assert sorted(losses)[-(STEPS + 1 - first_logged):] == list(range(first_logged, STEPS + 1))
  assert max(abs(losses[s] - ref_losses[s]) for s in losses) < TOLERANCE, (losses, ref_losses)


def test_two_processes_train_like_one(tmp_path, scene_dir, one_process):
  run = tmp_path / 'two'
  _finish(_launch(scene_dir, run))
  _assert_close(_state(scene_dir, run), _losses(run), one_process)
  assert sorted(os.listdir(run)) == ['checkpoints', 'config.gin', 'config.json', run_dir_lib.MARKER_FILE,
                                     learning_curve.CSV_FILE, learning_curve.CLOCK_FILE, 'tensorboard']
  assert len(glob.glob(str(run / 'tensorboard' / 'events.*'))) == 1  # Written by process 0 only.
  curve, ref_curve = learning_curve.read_rows(learning_curve.csv_path(run)), one_process[2]
  assert [r['step'] for r in curve] == [r['step'] for r in ref_curve] == [STEPS]  # The demo's curve: last step only.
  assert abs(curve[0]['psnr'] - ref_curve[0]['psnr']) < 1e-3


@pytest.mark.slow
def test_two_processes_killed_after_a_checkpoint_resume_like_one(tmp_path, scene_dir, one_process):
  run = tmp_path / 'killed'
  procs = _launch(scene_dir, run)
  deadline = time.time() + TIMEOUT_S
  folder = run / 'checkpoints'
  while not any(n.isdigit() and not checkpoints.damage(str(folder / n))
                for n in (os.listdir(folder) if folder.is_dir() else [])):
    assert time.time() < deadline and all(p.poll() is None for p in procs), 'no checkpoint before the kill'
    time.sleep(0.05)
  for proc in procs:
    proc.send_signal(signal.SIGKILL)
  for proc in procs:
    proc.wait()
  killed_at = checkpoints.latest_step(str(run))
  assert 2 <= killed_at < STEPS
  _finish(_launch(scene_dir, run))
  # Tensorboard events not yet flushed when killed are lost; the resumed run logs the steps after killed_at.
  _assert_close(_state(scene_dir, run), _losses(run), one_process, first_logged=killed_at + 1)


@pytest.mark.parametrize('flags, message', [
    (['--num_processes', '0'], r'--num_processes = 0 must be >= 1'),
    (['--num_processes', '2', '--process_id', '2', '--coordinator_address', 'h:1'],
     r'--process_id = 2 must be in 0 \.\. 1'),
    (['--num_processes', '2'], r"--coordinator_address = '' must be HOST:PORT")])
def test_inconsistent_process_flags_are_errors_naming_the_flag(flags, message, monkeypatch):
  for name in distributed.ENV.values():
    monkeypatch.delenv(name, raising=False)
  parser = argparse.ArgumentParser()
  distributed.add_flags(parser)
  with pytest.raises(ValueError, match=message):
    distributed.initialize(parser.parse_args(flags))
