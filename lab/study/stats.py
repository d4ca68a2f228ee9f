"""Statistics of a study over its replicates (the seed axis): per cell mean, spread and n, and paired
differences between methods or axis points with a 95% confidence interval (Student's t over the pairs).

At the budgets a CPU affords, a seed moves a method by several dB, so a single run ranks nothing: a comparison
whose interval contains zero is reported as undecided, in the table and the plot.

A study read at several seed counts (3 seeds, every interval holding 0, then 2 more; the study's `looks`) had as many
chances to declare a difference where there is none: with a null difference, "look at 3, add 2, look again" declares
one 8.7% of the time at 95% per look. Each interval is then at level 1 - 0.05 / k for k looks (Bonferroni: the looks
together err at most 5% of the time; 4.5% for that case), look_level.
"""

import dataclasses
import math
import statistics
from typing import Dict, List, Optional, Sequence, Tuple

from scipy import stats as scipy_stats

from lab.study import spec as study_spec

LEVEL = 0.95  # Confidence level of the paired intervals.
UNDECIDED = 'UNDECIDED'


def finite(value) -> Optional[float]:
  """A finite float, or None."""
  try:
    value = float(value)
  except (TypeError, ValueError):
    return None
  return value if math.isfinite(value) else None


def label_keys(study: study_spec.Study) -> List[str]:
  """The labels that tell cells apart: method, scene and every axis."""
  return ['method', 'scene'] + [a.name for a in study.axes]


def spread(values: Sequence[float]) -> dict:
  """{'mean', 'std' (sample, n - 1; None for one value), 'n'} of values."""
  return {'mean': statistics.fmean(values), 'std': statistics.stdev(values) if len(values) > 1 else None,
          'n': len(values)}


def by_labels(study: study_spec.Study, rows: List[dict], metric: str) -> Dict[tuple, float]:
  """{every label of a row (label_keys order): its finite metric}; a ValueError naming labels that two rows share
  (one setting and seed run twice: pooled it would count twice, paired one value would drop the other)."""
  keys, values = label_keys(study), {}
  for row in rows:
    value, labels = finite(row.get(metric)), tuple(row.get(k) for k in keys)
    if value is None:
      continue
    if labels in values:
      named = ', '.join(f'{k} {v}' for k, v in zip(keys, labels))
      raise ValueError(f'two results for {named} ({metric}: {values[labels]:g} and {value:g}); expected one row per '
                       'setting and seed, so that no seed counts twice')
    values[labels] = value
  return values


def summarize(study: study_spec.Study, rows: List[dict], metric: str) -> List[dict]:
  """Per group of rows equal on every label but the seed: the labels, the metric's mean, std and n."""
  all_keys = label_keys(study)
  keys = [k for k in all_keys if k != study_spec.SEED_AXIS]
  groups: Dict[tuple, List[float]] = {}
  for labels, value in by_labels(study, rows, metric).items():
    found = dict(zip(all_keys, labels))
    groups.setdefault(tuple(found[k] for k in keys), []).append(value)
  return [{**dict(zip(keys, labels)), 'metric': metric, **spread(values)} for labels, values in groups.items()]


def seed_count(study: study_spec.Study) -> Optional[int]:
  """The number of seeds of the study's seed axis, None without one."""
  return next((len(a.points) for a in study.axes if a.name == study_spec.SEED_AXIS), None)


def looks(study: study_spec.Study) -> Tuple[int, ...]:
  """The seed counts at which the study's comparisons are read: its `looks` and its seed count; () without seeds."""
  count = seed_count(study)
  return () if count is None else tuple(sorted(set(study.looks) | {count}))


def look_level(study: study_spec.Study) -> float:
  """The level of each interval of the study: LEVEL for one look, 1 - (1 - LEVEL) / k for k looks."""
  return 1. - (1. - LEVEL) / max(1, len(looks(study)))


def level_text(level: float) -> str:
  """'95%', '97.5%': a level as a percentage."""
  return f'{100 * level:.4g}%'


def t_interval(differences: Sequence[float], level: float = LEVEL) -> Tuple[float, Optional[float], Optional[float]]:
  """(mean, low, high) of the mean of paired differences [n]: Student's t interval; (mean, None, None) for n = 1."""
  n = len(differences)
  mean = statistics.fmean(differences)
  if n < 2:
    return mean, None, None
  half = scipy_stats.t.ppf(0.5 + level / 2, n - 1) * statistics.stdev(differences) / math.sqrt(n)
  return mean, mean - half, mean + half


@dataclasses.dataclass(frozen=True)
class Comparison:
  """The paired difference a - b of a metric over n matched pairs, with its interval and verdict."""
  axis: str
  a: str
  b: str
  metric: str
  n: int
  mean: float
  low: Optional[float]
  high: Optional[float]
  lower_is_better: bool
  level: float = LEVEL  # Of the interval: above LEVEL where corrected for several looks.

  @property
  def verdict(self) -> str:
    """'<label> better' when the interval excludes 0, else UNDECIDED with the reason."""
    if self.low is None:
      return f'{UNDECIDED}: {self.n} pair, no interval'
    if self.low <= 0. <= self.high:
      return f'{UNDECIDED}: the {level_text(self.level)} interval contains 0'
    a_better = (self.mean > 0) != self.lower_is_better
    return f'{self.a if a_better else self.b} better'

  def row(self) -> dict:
    """The comparison as a CSV row."""
    return {'axis': self.axis, 'a': self.a, 'b': self.b, 'metric': self.metric, 'n': self.n,
            'mean_a_minus_b': self.mean, 'ci_low': self.low, 'ci_high': self.high, 'verdict': self.verdict}


def pairs(study: study_spec.Study, rows: List[dict], compare: study_spec.Compare, metric: str) -> List[float]:
  """a - b of metric for every pair of rows labelled a and b on compare.axis and equal on every other label."""
  keys = label_keys(study)
  values = {}
  for labels, value in by_labels(study, rows, metric).items():
    found = dict(zip(keys, labels))
    if found[compare.axis] in (compare.a, compare.b):
      values[(found[compare.axis], tuple(v for k, v in found.items() if k != compare.axis))] = value
  return [value - values[(compare.b, match)] for (label, match), value in values.items()
          if label == compare.a and (compare.b, match) in values]


def compare(study: study_spec.Study, rows: List[dict], metric: str) -> List[Comparison]:
  """The study's comparisons on metric (those with at least one pair), each interval at look_level."""
  found, level = [], look_level(study)
  for entry in study.compare:
    differences = pairs(study, rows, entry, metric)
    if differences:
      found.append(Comparison(entry.axis, entry.a, entry.b, metric, len(differences), *t_interval(differences, level),
                              study_spec.is_lower_better(metric), level))
  return found
