"""Accuracy at a training-time budget, from the cells' learning curves (a metric against elapsed training seconds).

A run with learning curves gives its whole trade between time and accuracy: at a budget of b seconds its value is
that of the last curve point recorded within b (what stopping there would have kept). Per budget of the study's
`[plot] budgets` and per setting (every label but the seed) this gives the mean, spread and n over seeds; the best
setting; and its paired difference to the runner-up over the seeds both reached, with the interval and verdict of
lab/study/stats.py, so a budget where the choice is not decided says so. The best is chosen on these same seeds,
so a plain 95% interval for its lead would be too narrow; the interval holds 95% simultaneously for all k(k - 1)/2
pairs of the k settings (Bonferroni), so it stays valid for whichever pair the choice picked; and for every look of a
study read at several seed counts (stats.looks), as its comparisons are.
"""

import os
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from internal import runs
from lab.study import plots as study_plots
from lab.study import spec as study_spec
from lab.study import stats as study_stats

Curve = List[Tuple[float, float]]  # (training seconds, value), by seconds.


def value_at(curve: Curve, budget: float) -> Optional[float]:
  """The value of the last point of curve recorded within budget seconds; None before its first point."""
  within = [value for seconds, value in curve if seconds <= budget]
  return within[-1] if within else None


def setting_curves(study: study_spec.Study, curve_rows: List[dict], metric: str) -> Dict[str, Dict[str, Curve]]:
  """{setting label: {seed: curve}} of metric: a setting is the labels other than the seed (the scene only when
  the study has several)."""
  keys = [k for k in study_stats.label_keys(study)
          if k != study_spec.SEED_AXIS and (k != 'scene' or len(study.scenes) > 1)]
  found: Dict[str, Dict[str, Curve]] = {}
  for row in curve_rows:
    seconds, value = study_stats.finite(row.get('seconds')), study_stats.finite(row.get(metric))
    if seconds is not None and value is not None:
      setting = ' '.join(str(row.get(k)) for k in keys)
      found.setdefault(setting, {}).setdefault(str(row.get(study_spec.SEED_AXIS)), []).append((seconds, value))
  return {s: {seed: sorted(c) for seed, c in seeds.items()} for s, seeds in found.items()}


def _at_budget(curves: Dict[str, Dict[str, Curve]], budget: float) -> Dict[str, Dict[str, float]]:
  """{setting: {seed: value at budget}} of the settings that reached a curve point within budget."""
  values = {s: {seed: value_at(c, budget) for seed, c in seeds.items()} for s, seeds in curves.items()}
  return {s: {seed: v for seed, v in by_seed.items() if v is not None} for s, by_seed in values.items()
          if any(v is not None for v in by_seed.values())}


def selection_level(settings: int, looks: int = 1) -> float:
  """The level of each pair's interval that makes all settings x (settings - 1) / 2 pairs at each of looks hold
  together at study_stats.LEVEL (Bonferroni): valid for the pair of the best and the runner-up, chosen after seeing
  them."""
  return 1. - (1. - study_stats.LEVEL) / max(1, settings * (settings - 1) // 2) / max(1, looks)


def budget_row(values: Dict[str, Dict[str, float]], budget: float, metric: str, looks: int = 1) -> dict:
  """The best setting at one budget, its spread, and the paired comparison with the runner-up (its interval
  corrected for the choice and the looks: selection_level)."""
  sign = -1. if study_spec.is_lower_better(metric) else 1.
  ranked = sorted(values, key=lambda s: -sign * study_stats.spread(list(values[s].values()))['mean'])
  best = ranked[0]
  row = {'budget_s': budget, 'metric': metric, 'best': best, **study_stats.spread(list(values[best].values()))}
  if len(ranked) > 1:
    runner_up = ranked[1]
    shared = sorted(set(values[best]) & set(values[runner_up]))
    differences = [values[best][seed] - values[runner_up][seed] for seed in shared]
    interval = study_stats.t_interval(differences, selection_level(len(ranked), looks)) if differences else None
    comparison = study_stats.Comparison('setting', best, runner_up, metric, len(differences), *interval,
                                        sign < 0) if differences else None
    row.update(runner_up=runner_up,
               runner_up_mean=study_stats.spread(list(values[runner_up].values()))['mean'],
               **({k: comparison.row()[k] for k in ('mean_a_minus_b', 'ci_low', 'ci_high', 'verdict')}
                  if comparison else {'verdict': f'{study_stats.UNDECIDED}: no seed reached both'}))
  return row


def budget_rows(study: study_spec.Study, curve_rows: List[dict], metric: str,
                budgets: Sequence[float]) -> List[dict]:
  """budget_row of every budget that some setting reached."""
  curves, looks = setting_curves(study, curve_rows, metric), len(study_stats.looks(study))
  return [budget_row(values, budget, metric, looks) for budget in budgets
          if (values := _at_budget(curves, budget))]


def _cell(value, digits: int = 2) -> str:
  return '' if value is None else f'{value:.{digits}f}'


def budget_markdown(rows: List[dict], looks: int = 1) -> str:
  """The per-budget choice as a Markdown table (undecided verdicts in bold)."""
  corrected = 'choosing the best' + (f' and {looks} looks' if looks > 1 else '')
  lines = ['| budget (s) | metric | best setting | mean | std | n | runner-up (mean) | best - runner-up '
           f'[95% interval, corrected for {corrected}] | verdict |', '|---|---|---|---|---|---|---|---|---|']
  for r in rows:
    verdict = r.get('verdict', 'only setting')
    verdict = f'**{verdict}**' if verdict.startswith(study_stats.UNDECIDED) else verdict
    runner = f"{r['runner_up']} ({_cell(r['runner_up_mean'])})" if 'runner_up' in r else ''
    interval = (f"{_cell(r.get('mean_a_minus_b'))} [{_cell(r.get('ci_low'))}, {_cell(r.get('ci_high'))}]"
                if r.get('mean_a_minus_b') is not None else '')
    lines.append(f"| {r['budget_s']:g} | {r['metric']} | {r['best']} | {_cell(r['mean'])} | {_cell(r['std'])} | "
                 f"{r['n']} | {runner} | {interval} | {verdict} |")
  return '\n'.join(lines) + '\n'


def mean_curve(seeds: Dict[str, Curve], grid: np.ndarray) -> Curve:
  """(t, mean over the seeds that reached t) on grid, from t on where every seed has a value."""
  values = [[value_at(curve, t) for curve in seeds.values()] for t in grid]
  return [(float(t), float(np.mean(v))) for t, v in zip(grid, values) if all(x is not None for x in v)]


def curve_plot(study: study_spec.Study, curve_rows: List[dict], metric: str, path: str) -> bool:
  """<metric> against training seconds as steps (a value holds until the next point): each seed thin, each
  setting's mean over seeds thick, the front of the means dashed; False (nothing written) without curves."""
  curves = setting_curves(study, curve_rows, metric)
  if not curves:
    return False
  end = max(s for seeds in curves.values() for c in seeds.values() for s, _ in c)
  grid = np.linspace(0., end, 200)
  means = {setting: mean_curve(seeds, grid) for setting, seeds in curves.items()}
  fig, ax = runs.line_figure({f'{s} (mean of {len(curves[s])})': m for s, m in means.items() if m})
  for line, setting in zip(ax.get_lines(), [s for s, m in means.items() if m]):
    line.set_marker('')
    for curve in curves[setting].values():
      ax.plot(*zip(*curve), color=line.get_color(), alpha=.35, linewidth=.8, marker='.', drawstyle='steps-post')
  front = study_plots.pareto_front([p for m in means.values() for p in m], study_spec.is_lower_better(metric))
  if front:
    ax.plot(*zip(*front), color='black', linestyle='--', linewidth=1., label='front of the means',
            drawstyle='steps-post')
  runs.save_figure(fig, ax, 'training seconds', f'{metric} (learning-curve views)',
                  f'{study.name}: {metric} against training time', path)
  return True


def write_budget_results(study: study_spec.Study, curve_rows: List[dict], out_dir: str,
                         metrics: Sequence[str]) -> List[str]:
  """<metric>_vs_seconds.png for every metric with curves, and budgets.md when the study names budgets."""
  written = []
  for metric in metrics:
    path = os.path.join(out_dir, f'{metric}_vs_seconds.png')
    if curve_plot(study, curve_rows, metric, path):
      written.append(path)
  rows = [r for metric in metrics for r in budget_rows(study, curve_rows, metric, study.plot.budgets)]
  if rows:
    path = os.path.join(out_dir, 'budgets.md')
    with open(path, 'w', encoding='utf-8') as f:
      f.write(budget_markdown(rows, len(study_stats.looks(study))))
    written.append(path)
  return written
