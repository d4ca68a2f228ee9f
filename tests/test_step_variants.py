"""bench.step_variants: which variant a run may take (fastest), and a failed or wrong variant measured end to end."""

import json

import gin
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bench import step_variants


def _measured(base_ms, precision='bfloat16', **variants):
  """A step_variants report: base and {variant: (step ms, first loss difference, gradients' relative L2 (all
  together and the worst array's, or one number for both))}."""
  results = {'base': {'step_seconds': base_ms / 1e3, 'loss': 0.5}}
  for name, (ms, gap, grad) in variants.items():
    together, worst = grad if isinstance(grad, tuple) else (grad, grad)
    results[name] = {'step_seconds': ms / 1e3, 'loss_difference': gap, 'gradient_relative_l2': together,
                     'gradient_worst_relative_l2': worst, 'gradient_worst_leaf': "['mlp']['Dense_1']['bias']"}
  return {'platform': 'gpu', 'results': {precision: results}}


def test_runs_pick_the_fastest_variant_that_takes_gin_bindings_and_kept_the_loss_and_gradients():
  fastest = step_variants.fastest
  assert fastest(_measured(28, pallas=(15, 1e-4, 1e-3), pallas_rows128=(14, 1e-4, 1e-3)), 'bfloat16') == \
      'pallas_rows128'
  # An XLA option is no run's binding; a variant whose first step moved the loss is not trusted.
  assert fastest(_measured(28, cublaslt=(10, 0, 0), pallas=(12, 0.01, 0)), 'bfloat16') == 'base'
  assert fastest(_measured(28, pallas=(30, 0, 0)), 'bfloat16') == 'base'
  assert fastest(_measured(28, pallas=(15, 0, 0)), 'default') == 'base'  # Not measured there.
  # Gradients: relative L2 below 2e-2 in bfloat16 and TF32, 1e-5 in float32; NaN or unchecked is refused.
  assert fastest(_measured(28, pallas=(15, 0, 3e-2), pallas_rows128=(16, 0, 1e-2)), 'bfloat16') == \
      'pallas_rows128'
  assert fastest(_measured(28, 'default', pallas=(15, 0, 1e-2)), 'default') == 'pallas'
  assert fastest(_measured(28, 'float32', pallas=(15, 0, 1e-2)), 'float32') == 'base'
  assert fastest(_measured(28, 'float32', pallas=(15, 0, 5e-6)), 'float32') == 'pallas'
  assert fastest(_measured(28, pallas=(15, 0, float('nan'))), 'bfloat16') == 'base'
  # Each parameter array within 10 times that: deep, small arrays round more; one wrong array is refused.
  assert fastest(_measured(28, 'float32', pallas=(15, 0, (5e-6, 5e-5))), 'float32') == 'pallas'
  assert fastest(_measured(28, 'float32', pallas=(15, 0, (5e-6, 2e-4))), 'float32') == 'base'
  assert fastest(_measured(28, pallas=(15, 0, (1e-3, 0.5))), 'bfloat16') == 'base'
  unchecked = _measured(28, pallas=(15, 0, 0))
  del unchecked['results']['bfloat16']['pallas']['gradient_worst_relative_l2']
  assert fastest(unchecked, 'bfloat16') == 'base'
  on_cpu = dict(_measured(28, 'default', pallas=(15, 0, 1e-3)), platform='cpu')  # 'default' is float32 there.
  assert fastest(on_cpu, 'default') == 'base'


def test_bindings_print_the_variant_then_its_gin_lines(tmp_path, capsys):
  measured = tmp_path / 'step_variants.json'
  measured.write_text(json.dumps(_measured(28, pallas_block64=(15, 0, 0))))
  step_variants.main(['--bindings', 'fastest', '--precisions', 'bfloat16', '--measured', str(measured)])
  assert capsys.readouterr().out.splitlines() == ['pallas_block64', "MLP.dense_kernel = 'pallas'",
                                                  'FusedDenseTiles.block = 64', 'FusedDenseTiles.num_warps = 4']
  step_variants.main(['--bindings', 'fastest', '--precisions', 'bfloat16', '--measured', str(tmp_path / 'none')])
  assert capsys.readouterr().out == 'base\n'
  with pytest.raises(ValueError, match=r"step variant 'cublaslt' sets XLA options \['xla_gpu_enable_cublaslt'\]"):
    step_variants.main(['--bindings', 'cublaslt'])


@jax.custom_vjp
def _relu_passing_zeros(x):
  """ReLU whose gradient passes where its output is 0 too (y >= 0 for y > 0: a kernel bug that keeps the loss)."""
  return jnp.maximum(x, 0)


_relu_passing_zeros.defvjp(lambda x: (jnp.maximum(x, 0),) * 2, lambda y, g: (jnp.where(y >= 0, g, 0),))
gin.external_configurable(_relu_passing_zeros, name='relu_passing_zeros')
ERROR = '\n'.join(f'line {i} of a long compiler error' for i in range(40))


@pytest.mark.slow
def test_a_wrong_gradient_is_refused_and_a_failing_variant_keeps_its_error_and_not_the_others(
    tmp_path, monkeypatch, capsys):
  fakes = {'wrong_gradient': (('MLP.net_activation = @relu_passing_zeros',), {}),
           'fails_to_build': ((), {}), 'fails_when_timed': ((), {})}
  for name, variant in fakes.items():
    monkeypatch.setitem(step_variants.VARIANTS, name, variant)
  build = step_variants.build

  def failing_build(variant, *args):
    if variant == 'fails_to_build':
      raise RuntimeError(ERROR)
    run, figures = build(variant, *args)
    if variant != 'fails_when_timed':
      return run, figures
    return (lambda: (_ for _ in ()).throw(ValueError('the kernel stopped'))), figures
  monkeypatch.setattr(step_variants, 'build', failing_build)
  step_variants.main(['--tiny', '--batch_size', '64', '--repeats', '2', '--precisions', 'float32',
                      '--profile_steps', '0', '--out_dir', str(tmp_path),
                      '--variants', 'relu_from_output,wrong_gradient,fails_to_build,fails_when_timed'])
  log = capsys.readouterr().out
  report = json.loads((tmp_path / 'step_variants.json').read_text())
  results = report['results']['float32']
  # The wrong gradient keeps the first loss; its gradients are what give it away.
  wrong = results['wrong_gradient']
  assert wrong['loss_difference'] == 0 and wrong['gradient_worst_relative_l2'] > 1e-3
  assert wrong['refused'].startswith('gradients off') and 'refused: gradients off' in log
  assert results['relu_from_output']['gradient_relative_l2'] == 0 and not results['relu_from_output']['refused']
  # Even as the fastest it is not taken.
  for name, seconds in (('base', 1.), ('relu_from_output', .9), ('wrong_gradient', .1)):
    results[name]['step_seconds'] = seconds
  assert step_variants.fastest(report, 'float32') == 'relu_from_output'
  # A failure keeps its error's last 30 lines, in the JSON and in the log, and costs the others nothing.
  failed = results['fails_to_build']
  assert failed['unavailable'] == 'build: RuntimeError: line 0 of a long compiler error'
  assert len(failed['error_tail']) == 30 and failed['error_tail'][-1] == 'line 39 of a long compiler error'
  assert '  line 39 of a long compiler error' in log and '  line 9 of' not in log
  timed = results['fails_when_timed']
  assert timed['unavailable'] == 'timing: ValueError: the kernel stopped' and 'step_seconds' not in timed
  assert timed['error_tail'][-1] == 'ValueError: the kernel stopped'
  assert all(np.isfinite(results[name]['step_seconds']) for name in ('base', 'relu_from_output'))
  assert 'unavailable: build: RuntimeError' in log


def test_variants_past_the_build_budget_are_left_unbuilt_and_those_built_are_timed(tmp_path):
  # The plain step is built first, within the budget; building it takes longer than the whole budget.
  step_variants.main(['--tiny', '--batch_size', '64', '--repeats', '1', '--precisions', 'float32',
                      '--profile_steps', '0', '--out_dir', str(tmp_path), '--build_seconds', '0.001',
                      '--variants', 'relu_from_output'])
  results = json.loads((tmp_path / 'step_variants.json').read_text())['results']['float32']
  assert results['relu_from_output'] == {'unavailable': 'not built: --build_seconds 0.001 spent on the others'}
  assert np.isfinite(results['base']['step_seconds'])
