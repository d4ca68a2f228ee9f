"""Twenty training steps of four settings, pinned bit for bit per machine kind: a change that should move no number
(a refactor of the step, the batch or the cameras, issue 58) must leave these hashes as they are.

Each case trains in-process as pipeline/loop.py does (the data, the seeded batcher, one device's mesh, the jitted
step) for STEPS steps and hashes the parameters (SHA-256 over every leaf's path, dtype, shape and bytes), and the
camera corrections and their Adam moments where the run refines its cameras. The record (pinned_steps.json) holds
one entry per machine kind, XLA's instruction set (environment.cpu_isa) and the jax version, since both change the
float32 arithmetic; on a kind with no entry the tests skip saying so. To record this machine's kind, on a commit whose
numbers are the ones to keep: FREENERF_RECORD_PINNED=1 python -m pytest -n 0 tests/test_pinned_steps.py
"""

import hashlib
import json
import os

import jax
import numpy as np
import pytest
from jax import random

from conftest import SHARED_DATA
from internal import cli
from internal import config_loader
from internal import datasets
from internal import environment
from internal.run import sharding
from internal.training import camera_refinement
from internal.training import train_step

RECORD = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'pinned_steps.json')
RECORD_ENV = 'FREENERF_RECORD_PINNED'
STEPS = 20
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LLFF, DTU = SHARED_DATA / 'llff' / 'fern', SHARED_DATA / 'dtu' / 'dtu_scan24'


def _demo(scene_dir):
  """The demo's FreeNeRF as `python train.py` runs it (plain NeRF on 2 views of the forward rig)."""
  return cli.DEMO_CONFIGS, [f"Config.data_dir = '{scene_dir}_pinned_forward'"]


def _dtu(scene_dir):
  """FreeNeRF's mini DTU config on scan24, at 128 rays a step."""
  del scene_dir
  return [os.path.join(REPO, 'configs', 'mini', 'dtu3_freenerf.gin')], [
      f"Config.data_dir = '{DTU.parent}'", "Config.dtu_scan = 'dtu_scan24'", "Config.dtu_mask_path = ''",
      'Config.allow_missing_test_views = True', 'Config.batch_size = 128']


def _regnerf(scene_dir):
  """RegNeRF's mini LLFF config on fern, at 128 rays and one 8 x 8 random-pose patch a step."""
  del scene_dir
  return [os.path.join(REPO, 'configs', 'mini', 'llff3_regnerf.gin')], [
      f"Config.data_dir = '{LLFF.parent}'", "Config.llff_scan = 'fern'", 'Config.batch_size = 128',
      'Config.batch_size_random = 64']


def _refine(scene_dir):
  """Camera refinement as studies/cameras_generated.toml runs it: 6 views of the object rig, each camera turned by 5
  degrees and moved by 5% of the camera distance, at 128 rays a step."""
  return [os.path.join(REPO, 'configs', 'demo.gin'), os.path.join(REPO, 'configs', 'common', 'camera_refinement.gin')], [
      f"Config.data_dir = '{scene_dir}_pinned_object'", 'Config.n_input_views = 6', 'Config.max_steps = 500',
      'Config.freq_reg_end = 250', 'Config.batch_size = 128', 'Config.camera_noise_rotation_deg = 5.',
      'Config.camera_noise_translation = 0.05', 'Config.camera_noise_seed = 0']


CASES = {'demo': (_demo, None), 'dtu_mini': (_dtu, DTU), 'llff_regnerf': (_regnerf, LLFF), 'refine': (_refine, None)}


def machine_kind() -> str:
  """The key of this machine's entry: the instruction set XLA compiles for and the jax version."""
  return f'{environment.cpu_isa()} jax {jax.__version__}'


def _digest(tree) -> str:
  """SHA-256 of every leaf of tree: its path, dtype, shape and bytes."""
  digest = hashlib.sha256()
  for path, leaf in jax.tree_util.tree_flatten_with_path(jax.device_get(tree))[0]:
    leaf = np.ascontiguousarray(leaf)
    digest.update(f'{jax.tree_util.keystr(path)} {leaf.dtype} {leaf.shape}'.encode())
    digest.update(leaf.tobytes())
  return digest.hexdigest()


def train(config, steps: int = STEPS):
  """(TrainState, stats) after steps steps of Config, as pipeline/loop.py trains (one device's mesh)."""
  mesh = sharding.data_mesh()
  data = datasets.load_dataset('train', config)
  batcher = datasets.make_batcher(data, config)
  init_key, key = random.split(random.PRNGKey(config.jax_rng_seed))
  cameras = camera_refinement.init(config, data) if config.optimize_cameras else None
  example = jax.tree.map(lambda x: x[:8], batcher(0).rays)
  model, state = train_step.create_train_state(config, init_key, example, cameras)
  state = sharding.replicate(state, mesh)
  step_fn = train_step.make_train_step(config, model)
  for step in range(1, steps + 1):
    state, stats = step_fn(state, sharding.shard_batch(batcher(step), mesh), key)
  return state, stats


def fingerprint(state, stats) -> dict:
  """{'params', 'cameras' (refining runs), 'loss'} of a trained state: hashes, and the last loss for the message."""
  out = {'params': _digest(state.params), 'loss': float(stats['loss'])}
  cameras = getattr(state, 'cameras', None)
  if cameras is not None:
    out['cameras'] = _digest({'free': cameras.free, 'opt_state': cameras.opt_state})
  return out


def _read_record() -> dict:
  if not os.path.isfile(RECORD):
    return {}
  with open(RECORD) as f:
    return json.load(f)


def _write_entry(case: str, found: dict) -> None:
  record = _read_record()
  record.setdefault(machine_kind(), {})[case] = found
  with open(RECORD + '.partial', 'w') as f:
    json.dump(record, f, indent=1, sort_keys=True)
    f.write('\n')
  os.replace(RECORD + '.partial', RECORD)


@pytest.mark.parametrize('case', CASES)
def test_twenty_steps_give_the_pinned_parameters(case, scene_dir):
  make, needs = CASES[case]
  if needs is not None and not needs.is_dir():
    pytest.skip(f'{needs} is absent')
  recording = bool(os.environ.get(RECORD_ENV))
  pinned = _read_record().get(machine_kind(), {}).get(case)
  if pinned is None and not recording:
    pytest.skip(f'no pinned hashes for machine kind {machine_kind()!r} in {RECORD}; record them on a commit whose '
                f'numbers are the ones to keep with {RECORD_ENV}=1')
  files, bindings = make(scene_dir)
  found = fingerprint(*train(config_loader.load_config(files, bindings)))
  if recording:
    _write_entry(case, found)
    return
  assert {k: v for k, v in found.items() if k != 'loss'} == {k: v for k, v in pinned.items() if k != 'loss'}, (
      f'{case}: the parameters after {STEPS} steps moved (loss {found["loss"]!r}, pinned {pinned["loss"]!r})')
