"""Plots of a study's results: a metric against an axis (one line per method / scene / other labels, the paper's
values dashed beside ours) or against a recorded cost (wall time, GFLOP per step) with the Pareto front marked.
With a seed axis each line is the mean over seeds with error bars of one standard deviation, each seed a dot;
the paired comparisons get a plot of their intervals, undecided ones marked in red."""

import math
import os
from typing import List, Sequence, Tuple

from internal import runs
from lab.study import spec as study_spec
from lab.study import stats as study_stats

# Learning-curve metrics (internal/evaluation/learning_curve.py) plotted against the training step.
# Of the training cameras, where they move (after the similarity, and without it where the frames are shared).
CAMERA_CURVE_METRICS = ('camera_rotation_deg', 'camera_translation', 'camera_rotation_deg_unaligned',
                        'camera_translation_unaligned')
CURVE_METRICS = ('psnr', 'psnr_masked') + CAMERA_CURVE_METRICS


def pareto_front(points: Sequence[Tuple[float, float]], lower_is_better: bool) -> List[Tuple[float, float]]:
  """Points [(cost, metric)] not dominated by a cheaper-or-equal, better-or-equal other point, by cost."""
  sign = -1. if lower_is_better else 1.
  front, best = [], -math.inf
  for cost, value in sorted(points, key=lambda p: (p[0], -sign * p[1])):
    if sign * value > best:
      front.append((cost, value))
      best = sign * value
  return front


def _axis_positions(study: study_spec.Study, x: str):
  """({label: position}, tick labels or None): numeric values, or indices for a categorical axis (and for the
  seeds, whose values are names, not quantities: 20200823 beside 1 and 2 would squeeze those together)."""
  axis = next((a for a in study.axes if a.name == x), None)
  if axis is None:
    return None, None
  if x != study_spec.SEED_AXIS and all(p.value is not None for p in axis.points):
    return {p.label: p.value for p in axis.points}, None
  return {p.label: float(i) for i, p in enumerate(axis.points)}, [p.label for p in axis.points]


def _series(study: study_spec.Study, rows: List[dict], x: str, metric: str, positions) -> dict:
  """{line name: [(x, y)]}: one line per method, scene and the labels of the axes other than x and the seed
  (the seeds of a line share its x values)."""
  others = [a.name for a in study.axes if a.name not in (x, study_spec.SEED_AXIS)]
  lines = {}
  for row in rows:
    y = study_stats.finite(row.get(metric))
    xv = positions.get(row.get(x)) if positions is not None else study_stats.finite(row.get(x))
    if y is None or xv is None:
      continue
    name = ' '.join([row['method'], row['scene']] + [f'{a}={row[a]}' for a in others])
    lines.setdefault(name, []).append((xv, y))
  return {name: sorted(points) for name, points in lines.items()}


def plot(study: study_spec.Study, rows: List[dict], x: str, metric: str, path: str) -> bool:
  """Draws metric against x into path (PNG); False (nothing written) when no cell has both values."""
  positions, ticks = _axis_positions(study, x)
  lines = _series(study, rows, x, metric, positions)
  if not lines:
    return False
  if study.has_seeds and x != study_spec.SEED_AXIS:
    fig, ax = _seed_figure(lines, joined=positions is not None)
  else:
    fig, ax = runs.line_figure(lines, joined=positions is not None and x != study_spec.SEED_AXIS)
  for curve in study.paper:
    if curve.metric == metric and curve.x == x:
      ax.plot(*zip(*curve.points), marker='x', linestyle='--', color='black',
              label=f'paper: {curve.method}' + (f' ({curve.source})' if curve.source else ''))
  if study.plot.pareto:
    front = pareto_front([p for points in lines.values() for p in points], study_spec.is_lower_better(metric))
    ax.step(*zip(*front), where='post', color='red', linewidth=1.5, alpha=.6, label='Pareto front')
    ax.scatter(*zip(*front), s=120, facecolors='none', edgecolors='red')
  if ticks:
    ax.set_xticks(range(len(ticks)), ticks, rotation=20)
  runs.save_figure(fig, ax, x, metric, f'{study.name}: {metric} vs {x}', path)
  return True


def _seed_figure(lines: dict, joined: bool) -> tuple:
  """(figure, axes): per line the mean over seeds at each x with +-1 std error bars, and every seed as a dot."""
  fig, ax = runs.line_figure({})
  for name, points in lines.items():
    xs = sorted({px for px, _ in points})
    groups = [study_stats.spread([py for px, py in points if px == x]) for x in xs]
    n = max(g['n'] for g in groups)
    line = ax.errorbar(xs, [g['mean'] for g in groups], yerr=[g['std'] or 0. for g in groups], marker='o',
                       capsize=4, linestyle='-' if joined else 'none', label=f'{name} (mean +-1 std, n={n})')
    ax.scatter(*zip(*points), s=12, alpha=.45, color=line[0].get_color())
  return fig, ax


def comparison_plot(study: study_spec.Study, comparisons, metric: str, path: str) -> bool:
  """Draws each comparison's paired mean difference and interval (95%, or more when corrected for several looks;
  red: undecided); False when none."""
  if not comparisons:
    return False
  fig, ax = runs.line_figure({})
  for i, c in enumerate(comparisons):
    undecided = c.verdict.startswith(study_stats.UNDECIDED)
    color = 'red' if undecided else 'black'
    if c.low is not None:
      ax.plot([c.low, c.high], [i, i], color=color, linewidth=2)
    ax.plot([c.mean], [i], marker='o', color=color)
    ax.annotate(f'{c.verdict} (n={c.n})', (c.mean, i), textcoords='offset points', xytext=(0, 7), ha='center',
                color=color, fontsize=8, fontweight='bold' if undecided else 'normal')
  ax.axvline(0., color='grey', linestyle='--')
  ax.set_yticks(range(len(comparisons)), [f'{c.a} - {c.b}' for c in comparisons])
  ax.set_ylim(-.6, len(comparisons) - .2)
  if any(c.verdict.startswith(study_stats.UNDECIDED) for c in comparisons):
    ax.plot([], [], color='red', label=f'{study_stats.UNDECIDED}: no difference shown')
  runs.save_figure(fig, ax, f'a - b: paired mean, {study_stats.level_text(comparisons[0].level)} interval', '',
                  f'{study.name}: {metric}, paired', path)
  return True


def write_plots(study: study_spec.Study, rows: List[dict], out_dir: str) -> List[str]:
  """<metric>_vs_<x>.png for every plotted metric and x that has data, and compare_<metric>.png for the paired
  comparisons; returns the written paths."""
  written = []
  for metric in study.plot.metrics:
    path = os.path.join(out_dir, f'compare_{metric}.png')
    if comparison_plot(study, study_stats.compare(study, rows, metric), metric, path):
      written.append(path)
  for x in study.plot.x:
    for metric in study.plot.metrics:
      path = os.path.join(out_dir, f'{metric}_vs_{x}.png')
      if plot(study, rows, x, metric, path):
        written.append(path)
  return written


def write_curve_plots(study: study_spec.Study, curve_rows: List[dict], out_dir: str) -> List[str]:
  """<metric>_vs_step.png of the cells' learning curves for every CURVE_METRICS that has data; the paths.

  curve_rows: one per cell and curve step, with the cell's method, scene and labels, as results rows.
  """
  written = []
  for metric in CURVE_METRICS:
    lines = _series(study, curve_rows, 'step', metric, None)
    if lines:
      path = os.path.join(out_dir, f'{metric}_vs_step.png')
      fig, ax = curve_figure(study, lines)
      scored = 'training cameras' if metric in CAMERA_CURVE_METRICS else 'learning-curve views'
      runs.save_figure(fig, ax, 'training step', f'{metric} ({scored})',
                      f'{study.name}: {metric} vs step', path)
      written.append(path)
  return written


def curve_figure(study: study_spec.Study, lines: dict) -> tuple:
  """(figure, axes) of learning curves {line: [(step, value)]}: with seeds a line's mean over them, each seed a
  dot (one line through every seed's points would zigzag at each step)."""
  return _seed_figure(lines, joined=True) if study.has_seeds else runs.line_figure(lines)
