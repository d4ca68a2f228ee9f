"""bench.profile_step: operations are charged to the stage of their source, and one scale's figures agree."""

import json
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bench import profile_step
from internal.models import encoding

STAGES = set(profile_step.FILE_STAGES.values()) | set(profile_step.DIR_STAGES.values()) | {
    'MLP matmuls', 'MLP activations and layout', 'losses', 'clipping and Adam', 'other (step glue)'}


def test_operations_of_the_encoding_are_charged_to_the_encoding():
  fn = jax.jit(lambda m, c: encoding.integrated_pos_enc(m, c, 0, 16))
  args = (jnp.ones((64, 3)), jnp.full((64, 3), 1e-3))
  sources = profile_step.operation_sources(fn.lower(*args).compile().as_text())
  stages = {profile_step.stage_of(source) for source in sources.values()}
  assert 'encoding' in stages and stages <= STAGES
  assert {file for file, _, _ in sources.values()} >= {'internal/models/encoding.py', 'internal/models/trig.py'}


def test_a_scale_reports_consistent_figures(tmp_path):
  out = tmp_path / 'profile.json'
  profile_step.main(['--scales', 'demo', '--repeats', '1', '--profile_steps', '1', '--out', str(out)])
  report = json.loads(out.read_text())['scales']['demo']
  assert report['achieved_gflops'] == pytest.approx(report['step_gflop'] / report['step_ms'] * 1e3)
  assert report['of_matmul_bench'] == pytest.approx(report['achieved_gflops'] / report['matmul_bench_gflops'])
  assert report['mlp_matmul_shape'] == [512 * 48, 64, 64]  # 512 rays x (16 + 32) fine samples, a 4 x 64 MLP.
  assert set(report['stage_ms']) <= STAGES and report['stage_ms']['MLP matmuls'] > 0
  assert report['traced_ms'] == pytest.approx(np.sum(list(report['stage_ms'].values())))
  assert report['dots_alone_of_step'] == pytest.approx(report['dots_alone_ms'] / report['step_ms'])


def test_unknown_scales_are_named():
  with pytest.raises(ValueError, match=r"--scales: unknown \['huge'\]"):
    profile_step.main(['--scales', 'demo,huge'])


def test_only_operations_that_multiply_matrices_count_as_matmuls():
  fn = jax.jit(lambda x, w: (x @ w, jnp.sum(x, axis=0)))  # A matmul and a bias-gradient-like column sum.
  hlo = fn.lower(jnp.ones((4096, 128)), jnp.ones((128, 128))).compile().as_text()
  matmuls = [name for name, (_, _, is_matmul) in profile_step.operation_sources(hlo).items() if is_matmul]
  output_shapes = {re.search(rf'%{re.escape(name)} = (\S+)', hlo).group(1).split('{')[0] for name in matmuls}
  assert output_shapes == {'f32[4096,128]'}


def test_the_module_dots_are_the_products_the_program_runs():
  a, b = jnp.ones((64, 5)), jnp.ones((7, 5))
  fn = jax.jit(lambda a, b, c: (a @ b.T, jnp.einsum('bik,bkj->bij', c, c)))
  c = jnp.ones((2, 8, 8))
  dots = profile_step.module_dots(fn.lower(a, b, c).compile().as_text())
  assert dots == {((64, 5), (7, 5), (((1,), (1,)), ((), ()))): 1,
                  ((2, 8, 8), (2, 8, 8), (((2,), (1,)), ((0,), (0,)))): 1}
  run = profile_step.dots_alone_runner(dots)
  assert run() > 0


def test_module_paths_are_read_from_the_projects_folders_wherever_the_checkout_was():
  assert profile_step.module_path('/elsewhere/clone/internal/models/trig.py') == 'internal/models/trig.py'
  assert profile_step.module_path('/venv/lib/python3.11/site-packages/optax/_src/transform.py') == \
      'optax/_src/transform.py'
  assert profile_step.stage_of(('optax/_src/transform.py', 'update_fn', False)) == 'clipping and Adam'
  assert profile_step.stage_of(('internal/losses/occlusion.py', 'occlusion_loss', False)) == 'losses'
  assert profile_step.module_path('<frozen runpy>') == '<frozen runpy>'
