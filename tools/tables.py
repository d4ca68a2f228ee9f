"""Gathers the metrics.json files of many runs into the paper's tables (Markdown + CSV).

Usage: python -m tools.tables RUN_ROOT... --out DIR [--allow-incomplete]

metrics.json: the record of internal/evaluation/results.py (written by eval.py; see results.RECORD_FIELDS).

A table's mean over scenes is the mean of the per-scene means, each the mean over test views (the paper's
convention, also for the 'Avg' column: the mean of per-image avg_error). A mean is only given over the full
scene list of the protocol (DTU: the 15 pixelNeRF test scans, LLFF: the 8 scenes), with every run complete and
the metric present; otherwise the cell is left empty and a warning names what is missing. --allow-incomplete
averages what exists instead and marks such means with '*'.

Runs of one scene that differ only in their seeds (metrics.json's `seeds`, written by eval.py) are replicates: the
scene's value is their mean, shown with the standard deviation over seeds and n; a summary mean over scenes is
shown with the standard deviation over seeds of the per-seed means when every scene has the same seeds.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import csv
import dataclasses
import pathlib
import statistics
import sys
from typing import Dict, List, Optional, Sequence, Tuple

from internal import cli
from internal.datasets import loader
from internal.evaluation import metric_registry
from internal.evaluation import results

# Column groups of the paper's tables per dataset: (label, metric keys), from the loaders' table groups.
METRIC_GROUPS = {name: tuple((label, metric_registry.names(group))
                             for label, group in loader.REGISTRY[name].table_groups) for name in results.DATASETS}
DISPLAY = {name: metric.display for name, metric in metric_registry.METRICS.items()}  # Column titles.
Key = Tuple[str, str, int, str]  # (dataset, method, n_input_views, scene)
# The FreeNeRF paper's means over scenes, shown beside the runs of the same method and views: Table 1 (Blender, 8
# views, NeRF-based) and the 3-view PSNRs of Tables 1 and 2 (LLFF; DTU object / full image). The baselines are the
# paper's own re-runs ("repro.": NeRF; mip-NeRF with the identity concatenated), not the numbers DietNeRF or
# RegNeRF reported for them; RegNeRF's row is the number RegNeRF reported, as the paper quotes it.
PAPER = {
    ('blender', 'nerf', 8): {'psnr': 13.93, 'ssim': 0.689, 'lpips': 0.320},
    ('blender', 'freenerf', 8): {'psnr': 24.26, 'ssim': 0.883, 'lpips': 0.098},
    ('llff', 'mipnerf', 3): {'psnr': 16.11}, ('llff', 'regnerf', 3): {'psnr': 19.08},
    ('llff', 'freenerf', 3): {'psnr': 19.63},
    ('dtu', 'mipnerf', 3): {'psnr_masked': 9.10, 'psnr': 7.94},
    ('dtu', 'regnerf', 3): {'psnr_masked': 18.89, 'psnr': 15.33},
    ('dtu', 'freenerf', 3): {'psnr_masked': 19.92, 'psnr': 18.02},
}
# Whose each PAPER row is, in its row label '<method> (<source>)'.
PAPER_SOURCE = {'nerf': "paper's repro. baseline", 'mipnerf': "paper's repro. baseline",
                'regnerf': 'reported by RegNeRF', 'freenerf': 'paper'}


def find_metrics_files(roots: Sequence[str]) -> List[pathlib.Path]:
  """metrics.json files under each root (a directory, searched recursively, or a file), without repeats."""
  found = []
  for root in map(pathlib.Path, roots):
    if not root.exists():
      raise FileNotFoundError(f'run root {str(root)!r} does not exist')
    found += [root] if root.is_file() else sorted(root.rglob(results.METRICS_FILENAME))
  return list(dict.fromkeys(path.resolve() for path in found))


def _seeds(record: dict) -> Optional[tuple]:
  """The record's seeds (jax, numpy) as a tuple, None for records written before seeds were recorded."""
  return tuple(record['seeds']) if record.get('seeds') is not None else None


def collect(paths: Sequence[pathlib.Path]) -> Tuple[Dict[Key, dict], List[str]]:
  """Records by (dataset, method, views, scene), replicates over seeds pooled (see pool_seeds); of several runs
  with the same seeds the highest step is kept, with a warning."""
  chosen, sources, warnings = {}, {}, []
  for path in paths:
    record = results.read_record(path)
    key = (record['dataset'], record['method'], record['n_input_views'], record['scene'], _seeds(record))
    if key in chosen:
      if chosen[key]['step'] == record['step']:
        raise ValueError(f'{sources[key]} and {path} both hold {key} at step {record["step"]}')
      if record['step'] < chosen[key]['step']:  # Keep the higher step in (path, record).
        path, record, sources[key], chosen[key] = sources[key], chosen[key], path, record
      warnings.append(f'{_label(key[:3])} {key[3]}: using step {record["step"]} ({path}), '
                      f'ignoring step {chosen[key]["step"]} ({sources[key]})')
    chosen[key], sources[key] = record, path
  return pool_seeds(chosen), warnings


def pool_seeds(records: Dict[tuple, dict]) -> Dict[Key, dict]:
  """{(dataset, method, views, scene): record} whose means are the mean over its seeds' records, with
  'std' {metric: standard deviation over seeds, None for one seed}, 'n_seeds' and 'by_seed' {seeds: means}."""
  replicates: Dict[Key, Dict[Optional[tuple], dict]] = {}
  for key, record in records.items():
    replicates.setdefault(key[:4], {})[key[4]] = record
  pooled = {}
  for key, by_seed in replicates.items():
    runs = list(by_seed.values())
    metrics = list(dict.fromkeys(m for r in runs for m in r['means']))
    values = {m: [r['means'].get(m) for r in runs] for m in metrics}
    pooled[key] = {**runs[0], 'step': min(r['step'] for r in runs), 'complete': all(r['complete'] for r in runs),
                   'means': {m: results.mean(v) for m, v in values.items()},
                   'std': {m: _std(v) for m, v in values.items()}, 'n_seeds': len(runs),
                   'by_seed': {seeds: r['means'] for seeds, r in by_seed.items()}}
  return pooled


def _std(values: Sequence[Optional[float]]) -> Optional[float]:
  """Sample standard deviation of values; None for fewer than two or a missing one."""
  return statistics.stdev(values) if len(values) > 1 and None not in values else None


@dataclasses.dataclass(frozen=True)
class Value:
  """A metric cell: number None = empty; mark '*' = mean over an incomplete set; std over seeds where known."""
  number: Optional[float]
  metric: str
  mark: str = ''
  std: Optional[float] = None


@dataclasses.dataclass
class Table:
  """An output table; `name` is its CSV file stem, rows hold str labels and Value cells."""
  name: str
  title: str
  header: List[str]
  rows: List[list]
  notes: List[str]


def _label(group: Tuple[str, str, int]) -> str:
  """(dataset, method, views) -> 'DTU freenerf 3 views'."""
  return f'{group[0].upper()} {group[1]} {group[2]} views'


def _gaps(scenes: Dict[str, dict], dataset: str) -> List[str]:
  """What keeps a group's means from covering the protocol's scene list, complete runs, every metric."""
  expected = results.EXPECTED_SCENES[dataset]
  present = [s for s in expected if s in scenes]
  gaps = []
  if len(present) < len(expected):
    gaps.append(f'missing scenes: {", ".join(s for s in expected if s not in scenes)}')
  partial = [s for s in present if not scenes[s]['complete']]
  if partial:
    gaps.append(f'incomplete runs (complete=false): {", ".join(partial)}')
  for _, metrics in METRIC_GROUPS[dataset]:
    for metric in metrics:
      lacking = [s for s in present if scenes[s]['means'].get(metric) is None]
      if lacking:
        gaps.append(f'{metric} missing for: {", ".join(lacking)}')
  return gaps


def _scene_mean(scenes: Dict[str, dict], dataset: str, metric: str, allow_incomplete: bool) -> Value:
  """Mean over the protocol's scenes of a metric; empty when incomplete, or marked '*' if allowed."""
  expected = results.EXPECTED_SCENES[dataset]
  values = [scenes[s]['means'].get(metric) for s in expected if s in scenes]
  usable = [v for v in values if v is not None]
  std = _seed_spread([scenes[s] for s in expected if s in scenes], metric)
  if len(usable) == len(expected) and all(scenes[s]['complete'] for s in expected):
    return Value(results.mean(usable), metric, std=std)
  if allow_incomplete and usable:
    return Value(results.mean(usable), metric, '*', std)
  return Value(None, metric)


def _seed_spread(records: List[dict], metric: str) -> Optional[float]:
  """Standard deviation over seeds of the mean over records (scenes) per seed, when every record has the same
  two or more seeds; else None."""
  seeds = {frozenset(r.get('by_seed', {None: None})) for r in records}
  if len(seeds) != 1 or len(next(iter(seeds))) < 2:
    return None
  return _std([results.mean([r['by_seed'][seed].get(metric) for r in records]) for seed in next(iter(seeds))])


def _metric_columns(dataset: str) -> List[Tuple[str, str]]:
  """(column title, metric key) of a dataset's metric groups."""
  return [(f'{label} {DISPLAY[m]}'.strip(), m)
          for label, metrics in METRIC_GROUPS[dataset] for m in metrics]


def _note(gaps: List[str], allow_incomplete: bool) -> str:
  """A footnote for a group with gaps."""
  prefix = '* = mean over what exists only' if allow_incomplete else 'mean left empty'
  return f'{prefix} ({"; ".join(gaps)})'


def _scene_table(group: Tuple[str, str, int], scenes: Dict[str, dict], allow_incomplete: bool) -> Table:
  """Per-scene rows and the mean row of one (dataset, method, views) group."""
  dataset = group[0]
  columns = _metric_columns(dataset)
  extras = sorted(s for s in scenes if s not in results.EXPECTED_SCENES[dataset])
  rows = []
  for scene in results.EXPECTED_SCENES[dataset] + tuple(extras):
    record = scenes.get(scene)
    if record is None:
      rows.append([scene, '', '', 'missing'] + [Value(None, m) for _, m in columns])
      continue
    note = 'not a protocol scene' if scene in extras else ('' if record['complete'] else 'incomplete')
    rows.append([scene, str(record['step']), str(record['n_seeds']), note]
                + [Value(record['means'].get(m), m, std=record['std'].get(m)) for _, m in columns])
  rows.append(['mean', '', '', ''] + [_scene_mean(scenes, dataset, m, allow_incomplete) for _, m in columns])
  gaps = _gaps(scenes, dataset)
  notes = [_note(gaps, allow_incomplete)] if gaps else []
  notes += [f'{s} is not one of the protocol\'s test scenes: shown, not averaged' for s in extras]
  return Table(f'{dataset}_{group[1]}_{group[2]}views', _label(group) + ', per scene',
               ['scene', 'step', 'seeds', 'note'] + [title for title, _ in columns], rows, notes)


def _summary_tables(dataset: str, groups: Dict[Tuple[str, str, int], Dict[str, dict]],
                    allow_incomplete: bool) -> List[Table]:
  """One table per metric group: rows = methods, columns = views x metrics (means over scenes)."""
  methods = sorted({m for d, m, _ in groups if d == dataset})
  views = sorted({n for d, _, n in groups if d == dataset})
  notes = []
  for group in ((dataset, method, n) for method in methods for n in views):
    gaps = _gaps(groups[group], dataset) if group in groups else ['no runs']
    notes += [f'{_label(group)}: {_note(gaps, allow_incomplete)}'] if gaps else []
  tables = []
  for label, metrics in METRIC_GROUPS[dataset]:
    header = ['method'] + [f'{n} views {DISPLAY[m]}' for n in views for m in metrics]
    rows = [[method] + [_scene_mean(groups.get((dataset, method, n), {}), dataset, m, allow_incomplete)
                        for n in views for m in metrics] for method in methods]
    rows += _paper_rows(dataset, methods, views, metrics)
    name = f'{dataset}_summary' + (f'_{label}' if label else '')
    title = f'{dataset.upper()} {label + " " if label else ""}metrics, mean over scenes'
    tables.append(Table(name, title, header, rows, notes))
  return tables


def _paper_rows(dataset: str, methods, views, metrics) -> List[list]:
  """'<method> (<PAPER_SOURCE>)' rows of PAPER for the methods and views shown, when any metric has a value."""
  rows = []
  for method in methods:
    values = [PAPER.get((dataset, method, n), {}).get(m) for n in views for m in metrics]
    if any(v is not None for v in values):
      cells = [Value(v, m) for v, m in zip(values, [m for _ in views for m in metrics])]
      rows.append([f'{method} ({PAPER_SOURCE[method]})'] + cells)
  return rows


def build_tables(records: Dict[Key, dict],
                 allow_incomplete: bool) -> Tuple[Dict[str, List[Table]], List[str]]:
  """Tables per dataset (summaries, then per-scene tables) and warnings about incomplete sets."""
  groups: Dict[Tuple[str, str, int], Dict[str, dict]] = {}
  for (dataset, method, views, scene), record in records.items():
    groups.setdefault((dataset, method, views), {})[scene] = record
  tables: Dict[str, List[Table]] = {}
  warnings = []
  for group, scenes in sorted(groups.items()):
    table = _scene_table(group, scenes, allow_incomplete)
    tables.setdefault(group[0], []).append(table)
    warnings += [f'{_label(group)}: {note}' for note in table.notes]
  for dataset in tables:
    tables[dataset] = _summary_tables(dataset, groups, allow_incomplete) + tables[dataset]
  return tables, warnings


def _format(cell, digits: Optional[int], empty: str) -> str:
  """A cell as text: Value with `digits` decimals (None = paper precision), '' or `empty` when absent."""
  if not isinstance(cell, Value):
    return cell
  if cell.number is None:
    return empty + cell.mark
  places = digits if digits is not None else (2 if cell.metric.startswith('psnr') else 3)
  spread = f' ± {cell.std:.{places}f}' if cell.std is not None and digits is None else ''
  return f'{cell.number:.{places}f}{spread}{cell.mark}'


def to_markdown(table: Table) -> str:
  """A table as Markdown, with paper precision, '–' for empty cells and its notes as footnotes."""
  lines = [f'### {table.title}', '', '| ' + ' | '.join(table.header) + ' |',
           '|' + '---|' * len(table.header)]
  lines += ['| ' + ' | '.join(_format(c, None, '–') for c in row) + ' |' for row in table.rows]
  lines += [''] + [f'- {note}' for note in table.notes]
  return '\n'.join(lines) + '\n'


def _csv_cells(cells: list, with_std: bool) -> List[str]:
  """A row's cells as CSV text (6 decimals); with_std: each Value followed by its spread over seeds."""
  out = []
  for cell in cells:
    out.append(_format(cell, 6, ''))
    if with_std and isinstance(cell, Value):
      out.append(_format(Value(cell.std, cell.metric), 6, ''))
  return out


def write_csv(table: Table, path: pathlib.Path) -> None:
  """A table as CSV with 6 decimals and empty cells for missing values; where any value has a spread over
  seeds, a '<column> std' column follows each metric column."""
  with_std = any(isinstance(c, Value) and c.std is not None for row in table.rows for c in row)
  header = table.header
  if with_std:
    header = [x for title, cell in zip(table.header, table.rows[0])
              for x in ([title, f'{title} std'] if isinstance(cell, Value) else [title])]
  with open(path, 'w', newline='') as f:
    writer = csv.writer(f)
    writer.writerow(header)
    writer.writerows(_csv_cells(row, with_std) for row in table.rows)


def write_tables(tables: Dict[str, List[Table]], out_dir) -> List[pathlib.Path]:
  """Writes <dataset>.md (all its tables) and one <table name>.csv per table; returns the paths."""
  out = pathlib.Path(out_dir)
  out.mkdir(parents=True, exist_ok=True)
  written = []
  for dataset, dataset_tables in tables.items():
    md = out / f'{dataset}.md'
    md.write_text(f'# {dataset.upper()}\n\n' + '\n'.join(map(to_markdown, dataset_tables)))
    written.append(md)
    for table in dataset_tables:
      write_csv(table, out / f'{table.name}.csv')
      written.append(out / f'{table.name}.csv')
  return written


def main(argv: Optional[Sequence[str]] = None) -> int:
  """CLI entry point; returns the exit status."""
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('roots', nargs='+', metavar='RUN_ROOT', help='run directories or metrics.json files')
  parser.add_argument('--out', required=True, help='output directory for the .md and .csv tables')
  parser.add_argument('--allow-incomplete', action='store_true',
                      help='average over incomplete scene sets, marking such means with *')
  args = parser.parse_args(argv)
  paths = find_metrics_files(args.roots)
  if not paths:
    raise FileNotFoundError(f'no {results.METRICS_FILENAME} under {args.roots}; expected run directories evaluated '
                            'by eval.py (or their metrics.json files)')
  records, warnings = collect(paths)
  tables, table_warnings = build_tables(records, args.allow_incomplete)
  for warning in warnings + table_warnings:
    print(f'WARNING: {warning}', file=sys.stderr)
  for path in write_tables(tables, args.out):
    print(path)
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
