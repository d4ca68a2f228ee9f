"""The regularizers of the training loss, summed from one table by the step (training/train_step.compute_loss).

Each is a Term: its stats key and weighting Config setting, a switch config -> bool (a Python bool: a term that is
off is never traced) and a loss (config, rendered, batch, step) -> (its weighted loss, stats), where rendered holds
every ray family of the batch rendered once ({Batch field: losses/rendered.Rendered}, e.g. rendered['rays'] for the
training pixels, rendered['patch_rays'] for RegNeRF's patches) and batch is the datasets/batching.Batch with the
targets. The step adds the terms in the table's order. Adding a regularizer: its module in losses/ with the two
functions and one line here (docs/design.md, 'Adding a regularizer').
"""

from typing import Callable, NamedTuple, Optional

from internal.losses import depth_pearson
from internal.losses import depth_ranking
from internal.losses import depth_smoothness
from internal.losses import occlusion
from internal.losses import reconstruction
from internal.losses import sparse_depth


class Term(NamedTuple):
  """One regularizer of the training loss."""
  stats: str       # Its stats key (ending in 'level': one per level, the coarse ones times coarse_loss_mult).
  weight: str      # The Config setting that weights it (a skipped step's message names it, train_step.py).
  is_on: Callable  # config -> bool.
  loss: Callable   # (config, rendered, batch, step) -> (weighted loss, stats).
  weight_at: Optional[Callable] = None  # (config, step) -> its weight when scheduled, else Config's value.


TERMS = (
    Term('loss_occ', 'occ_reg_loss_mult', occlusion.is_on, occlusion.term),  # FreeNeRF's occlusion regularizer.
    Term('loss_distortion', 'distortion_loss_mult', reconstruction.distortion_on,
         reconstruction.distortion_term),  # mip-NeRF 360's distortion (an ablation).
    Term('depth_tv_level', 'depth_tvnorm_loss_mult', depth_smoothness.is_on, depth_smoothness.term,
         depth_smoothness.tv_weight),  # RegNeRF's depth smoothness.
    Term('loss_depth_rank', 'depth_rank_loss_mult', depth_ranking.is_on, depth_ranking.term),  # Depth priors:
    Term('loss_depth_pearson', 'depth_pearson_loss_mult', depth_pearson.is_on, depth_pearson.term),
    Term('loss_sfm_depth', 'sfm_depth_loss_mult', sparse_depth.is_on, sparse_depth.term),
)
