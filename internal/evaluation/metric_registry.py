"""The table of the metrics an evaluation writes, from which results, tables and studies derive their lists.

Adding a metric: compute it where its group is computed (metrics.py or depth_metrics.py) and add its line here.
"""

import dataclasses
from typing import Dict, Tuple

FULL = 'full'                  # Image metrics over every pixel (every dataset).
MASKED = 'masked'              # DTU object metrics: inside the evaluation mask, background set to white.
DEPTH = 'depth'                # Depth errors against exact depths (generated scenes).
PSEUDO_DEPTH = 'pseudo_depth'  # The depth errors against another run's depths (Config.depth_reference_dir).
SFM_DEPTH = 'sfm_depth'        # The depth errors at the capture's structure-from-motion points (captures).
# Training-camera errors where the cameras may move (camera_evaluation.py): medians over the training views against
# the reference cameras after a similarity, rotation in degrees, translation as a fraction of the camera distance;
# *_unaligned: without the similarity, where the cameras share the reference's frame; test_pose_*: how far
# test-time pose optimization moved the test cameras from where the similarity placed them (medians).
CAMERAS = 'cameras'
MASKED_SUFFIX = '_masked'
PSEUDO_PREFIX = 'pseudo_'
SFM_PREFIX = 'sfm_'


@dataclasses.dataclass(frozen=True)
class Metric:
  """One key of metrics.json: its column title, whether lower values are better, its group."""
  name: str
  display: str
  lower_is_better: bool
  group: str


# (name, display name, lower is better) of the image metrics (FULL, and MASKED with MASKED_SUFFIX) and of the
# depth errors (DEPTH, PSEUDO_DEPTH with PSEUDO_PREFIX, SFM_DEPTH with SFM_PREFIX).
_IMAGE = (('psnr', 'PSNR', False), ('ssim', 'SSIM', False), ('lpips', 'LPIPS', True), ('avg_error', 'Avg', True))
_DEPTH = (('depth_mae', 'depth MAE', True), ('depth_within_1pct', 'depth within 1%', False),
          ('depth_within_5pct', 'depth within 5%', False))

METRICS: Dict[str, Metric] = {m.name: m for m in (
    [Metric(name, display, lower, FULL) for name, display, lower in _IMAGE]
    + [Metric(name + MASKED_SUFFIX, display, lower, MASKED) for name, display, lower in _IMAGE]
    + [Metric(name, display, lower, DEPTH) for name, display, lower in _DEPTH]
    + [Metric(PSEUDO_PREFIX + name, 'pseudo ' + display, lower, PSEUDO_DEPTH) for name, display, lower in _DEPTH]
    + [Metric(SFM_PREFIX + name, 'SfM ' + display, lower, SFM_DEPTH) for name, display, lower in _DEPTH]
    + [Metric('camera_rotation_deg', 'camera rotation error (deg)', True, CAMERAS),
       Metric('camera_translation', 'camera translation error', True, CAMERAS),
       Metric('camera_rotation_deg_unaligned', 'camera rotation error without the similarity (deg)', True, CAMERAS),
       Metric('camera_translation_unaligned', 'camera translation error without the similarity', True, CAMERAS),
       Metric('test_pose_rotation_deg', 'test-time pose turn (deg)', True, CAMERAS),
       Metric('test_pose_translation', 'test-time pose shift', True, CAMERAS)])}


def names(group: str) -> Tuple[str, ...]:
  """The metric names of a group, in table order; ValueError for an unknown group."""
  found = tuple(m.name for m in METRICS.values() if m.group == group)
  if not found:
    raise ValueError(f'metric group {group!r}; expected one of {sorted({m.group for m in METRICS.values()})}')
  return found


def lower_is_better() -> Tuple[str, ...]:
  """The metric names whose lower values are better (errors, LPIPS)."""
  return tuple(m.name for m in METRICS.values() if m.lower_is_better)
