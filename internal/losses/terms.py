"""The regularizers of the training loss, summed from one table by the step (training/train_step.compute_loss).

Each is a Term: a switch config -> bool (a Python bool: a term that is off is never traced) and a loss
(config, rendered, batch, step) -> (its weighted loss, stats), where rendered holds every ray family of the batch
rendered once ({Batch field: losses/rendered.Rendered}, e.g. rendered['rays'] for the training pixels,
rendered['patch_rays'] for RegNeRF's patches) and batch is the datasets/batching.Batch with the targets. The step
adds the terms in the table's order. Adding a regularizer: its module in losses/ with the two functions and one line
here (docs/design.md, 'Adding a regularizer').
"""

from typing import Callable, NamedTuple

from internal.losses import depth_pearson
from internal.losses import depth_ranking
from internal.losses import depth_smoothness
from internal.losses import occlusion
from internal.losses import reconstruction
from internal.losses import sparse_depth


class Term(NamedTuple):
  """One regularizer of the training loss."""
  is_on: Callable  # config -> bool.
  loss: Callable   # (config, rendered, batch, step) -> (weighted loss, stats).


TERMS = (
    Term(occlusion.is_on, occlusion.term),                               # FreeNeRF's occlusion regularizer.
    Term(reconstruction.distortion_on, reconstruction.distortion_term),  # mip-NeRF 360's distortion (ablation).
    Term(depth_smoothness.is_on, depth_smoothness.term),                 # RegNeRF's depth smoothness.
    Term(depth_ranking.is_on, depth_ranking.term),                       # Depth priors: SparseNeRF's ranking,
    Term(depth_pearson.is_on, depth_pearson.term),                       # the patch-wise Pearson correlation,
    Term(sparse_depth.is_on, sparse_depth.term),                         # DS-NeRF's sparse depth.
)
