"""loop.StepReport: the bar counts steps whose stats were fetched (done), not steps dispatched."""

import io
import types

import jax.numpy as jnp
import pytest

from internal.pipeline import loop


class Writer:
  """Records tensorboard scalars as {tag: [(step, value)]}."""

  def __init__(self):
    self.scalars = {}

  def add_scalar(self, tag, value, step):
    self.scalars.setdefault(tag, []).append((step, value))


def _stats(skipped=False):
  return {'loss': jnp.float32(0.5), 'psnr': jnp.float32(20.), 'skipped': jnp.bool_(skipped),
          'loss_finite': jnp.bool_(True), 'grads_finite': jnp.bool_(not skipped), 'lr_valid': jnp.bool_(True),
          'update_finite': jnp.bool_(True)}


@pytest.mark.parametrize('policy', ['skip', 'raise'])
def test_bar_advances_by_the_fetched_steps_at_each_flush(policy, monkeypatch):
  monkeypatch.setattr(loop.progress, 'progress_kwargs', lambda: {'file': io.StringIO()})
  config = types.SimpleNamespace(max_steps=10, nonfinite_grad_policy=policy, max_skipped_steps=5, batch_size=64,
                                 stuck_warning_steps=0)
  writer = Writer()
  progress = loop.StepReport(config, writer, first_step=3)  # Resumed after step 2.
  assert progress.bar.n == 2
  for step in (3, 4, 5):
    progress.add(step, _stats(skipped=step == 4 and policy == 'skip'))  # 'raise' would stop the run.
    assert progress.bar.n == 2  # Dispatched, not yet fetched.
  progress.flush(5)
  assert progress.bar.n == 5
  progress.flush(5)  # An empty window moves nothing.
  progress.add(6, _stats())
  progress.flush(6)
  assert progress.bar.n == 6
  assert [s for s, _ in writer.scalars['train/loss']] == [5, 6]
  skipped = int(policy == 'skip')
  assert writer.scalars['train/skipped_steps'] == [(5, skipped), (6, skipped)]
  progress.close()
