"""Study files (TOML): methods x scenes x axes of gin bindings, expanded into cells; validated with clear errors.

A study file (see studies/*.toml):

  name = "example"                        # output folder <out>/<name>/
  bindings = ["MLP.net_width = 16"]       # applied to every cell after the method's configs
  [methods.<m>]  configs = [...]  bindings = [...]
  [scenes.<s>]   bindings = [...]
  [[axis]]  name = "T"  binding = "Config.freq_reg_end_fraction"  values = [0.1, 0.5]   # a swept binding, or
  [[axis]]  name = "M"  points = [{label = "M=5", value = 5, bindings = [...], configs = [...]}, ...]
  seeds = 3  (or [0, 1, 2])                 # replicates: the seed axis, last; binds both of a cell's seeds
  looks = [2, 3]                            # seed counts at which the comparisons were read (default [seeds])
  [[compare]]  a = "freenerf"  b = "mipnerf"  axis = "method"   # paired a - b over seeds and scenes (95% CI)
  [plot]  x = ["T"]  metrics = ["psnr"]  pareto = false  budgets = [60, 300]  # budgets: training seconds
  [resources]  num_gpus = 1  num_cpus = 4  max_retries = 3   # per cell on a Ray cluster (--executor ray)
  [[paper]]  method = "mipnerf"  metric = "psnr"  x = "ratio"  points = [[0.1, 17.62], [1.0, 9.01]]
  [evaluations.<e>]  bindings = ["Config.test_pose_steps = 100"]   # each finished cell evaluated again under
                                            # bookkeeping settings: columns <metric>@<e> (lab/study/evaluations.py)

Cells are the product methods x scenes x axis points. A cell's gin input, in order: the method's configs, the
points' configs, the study's, method's, scene's and points' bindings, then Config.expname and
Config.checkpoint_dir set by the runner. Configs and bindings are templates (str.format): {out} (the --out
root), {data_root} (--data_root), {study}, {method}, {scene} and each axis name (the cell's label on that axis);
write {{ and }} for literal braces.

Seeds: `seeds = N` (seeds 0 .. N-1) or a list adds the axis SEED_AXIS, whose point s binds Config.jax_rng_seed = s
(initialization, sampling noise) and Config.np_rng_seed = s (the ray batches). An axis of that name written by hand
is a seed axis too. Results over it are replicates: lab/study/stats.py gives per cell mean, spread and n, and each
[[compare]] entry (default: every other method against the first) the paired difference with its interval.

Looks: a study whose seeds were added after its comparisons were read (3 seeds, every interval holding 0, then 2
more) looked twice, and each look can declare a difference by chance: `looks = [3, 5]` lists the seed counts at which
they were read, increasing, the last the study's count (default: [count], the seed count fixed in advance). The
runner adds the looks it recorded itself (lab/study/looks.py) and corrects every interval for their number.
"""

import contextlib
import dataclasses
import itertools
import json
import os
import pathlib
import string
import tomllib
from typing import Dict, Iterator, List, Optional, Tuple

from internal import atomic
from internal import runs
from lab.study import evaluations as study_evaluations

# Axis named VIEWS_AXIS is the tables' view count: it stays out of Config.expname (the tables' method column).
REPO = str(pathlib.Path(__file__).resolve().parents[2])  # The repository: studies/, configs/, results/.
VIEWS_AXIS = 'views'
# Axis named SEED_AXIS holds replicates (statistics pool over it); it stays out of Config.expname too.
SEED_AXIS = 'seed'
SEED_BINDINGS = ('Config.jax_rng_seed', 'Config.np_rng_seed')
# Recorded per-cell numbers that can serve as a plot's x besides the axes.
RECORDED_X = ('train_seconds', 'eval_seconds', 'steps_per_sec', 'gflops_per_step', 'peak_rss_mb')
# Metrics where lower is better (the Pareto front keeps the low ones).
LOWER_IS_BETTER = runs.lower_is_better()


def is_lower_better(metric: str) -> bool:
  """Whether lower is better for a metric of results.csv (<metric>@<evaluation> as its metric)."""
  return metric.split('@')[0] in LOWER_IS_BETTER

# In a cell's folder: the cell's gin configs and bindings and its labels, written before it runs (this module
# writes and reads it, the one place that knows its form).
CELL_SPEC_FILE = 'cell_spec.json'


class StudyError(ValueError):
  """A study file does not follow the format; the message names the file and the key."""


@dataclasses.dataclass(frozen=True)
class Point:
  """One position on an axis: its label (folder and expname part), numeric value (None: categorical), gin."""
  label: str
  value: Optional[float]
  bindings: Tuple[str, ...] = ()
  configs: Tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Axis:
  name: str
  points: Tuple[Point, ...]


@dataclasses.dataclass(frozen=True)
class Method:
  name: str
  configs: Tuple[str, ...]
  bindings: Tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class Plot:
  """What to plot: each metric against each x (an axis or a recorded cost), optionally the Pareto front."""
  x: Tuple[str, ...]
  metrics: Tuple[str, ...]
  pareto: bool
  budgets: Tuple[float, ...] = ()  # Training seconds at which budgets.md picks the best setting (learning curves).


@dataclasses.dataclass(frozen=True)
class PaperCurve:
  """Values the paper reports for one method and metric against an axis (drawn beside ours)."""
  method: str
  metric: str
  points: Tuple[Tuple[float, float], ...]  # (x, value) pairs along the axis named x.
  x: str
  source: str


@dataclasses.dataclass(frozen=True)
class Compare:
  """A paired comparison: the cells labelled a minus those labelled b on `axis` ('method' or an axis name),
  matched on every other label (scene, seed, the other axes)."""
  axis: str
  a: str
  b: str


@dataclasses.dataclass(frozen=True)
class Resources:
  """What a cell asks of a Ray cluster: GPUs and CPUs (fractions allowed), and retries after a lost worker."""
  num_gpus: float = 0.
  num_cpus: float = 1.
  max_retries: int = 3


@dataclasses.dataclass(frozen=True)
class Study:
  """A parsed study file: its cells are the product methods x scenes x axis points."""
  name: str
  path: str
  bindings: Tuple[str, ...]
  methods: Tuple[Method, ...]
  scenes: Tuple[Tuple[str, Tuple[str, ...]], ...]
  axes: Tuple[Axis, ...]
  plot: Plot
  paper: Tuple[PaperCurve, ...]
  compare: Tuple[Compare, ...] = ()
  resources: Resources = Resources()
  looks: Tuple[int, ...] = ()  # Seed counts at which the comparisons were read (the study file's, and recorded).
  evaluations: Tuple[Tuple[str, Tuple[str, ...]], ...] = ()  # (name, bindings): lab/study/evaluations.py.

  @property
  def has_seeds(self) -> bool:
    return any(a.name == SEED_AXIS for a in self.axes)


@dataclasses.dataclass(frozen=True)
class Cell:
  """One run of a study: the method, scene and one point per axis; `gin` gives its configs and bindings."""
  study: str
  method: str
  scene: str
  points: Tuple[Tuple[str, Point], ...]

  @property
  def cell_id(self) -> str:
    """Folder name: method, scene and axis labels joined by '__'."""
    return '__'.join([self.method, self.scene] + [f'{axis}={p.label}' for axis, p in self.points])

  @property
  def expname(self) -> str:
    """Config.expname: the method plus the labels of every axis except the view count and the seed."""
    return '_'.join([self.method] + [f'{axis}={p.label}' for axis, p in self.points
                                     if axis not in (VIEWS_AXIS, SEED_AXIS)])

  def labels(self) -> Dict[str, str]:
    return {axis: p.label for axis, p in self.points}


class _Reader:
  """Typed access to a TOML table with errors naming the file and the key path."""

  def __init__(self, path: str):
    self.path = path

  def fail(self, key: str, message: str):
    raise StudyError(f'{self.path}: {key}: {message}')

  def get(self, table: dict, key: str, where: str, kind, default=dataclasses.MISSING):
    name = f'{where}.{key}' if where else key
    if key not in table:
      if default is dataclasses.MISSING:
        self.fail(name, f'missing (expected {kind.__name__})')
      return default
    value = table[key]
    if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
      self.fail(name, f'{value!r} is a {type(value).__name__}; expected {kind.__name__}')
    return value

  def strings(self, table: dict, key: str, where: str) -> Tuple[str, ...]:
    values = self.get(table, key, where, list, [])
    if not all(isinstance(v, str) for v in values):
      self.fail(f'{where}.{key}' if where else key, f'{values!r}; expected a list of strings')
    return tuple(values)

  def unknown(self, table: dict, allowed, where: str) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
      self.fail(where or 'top level', f'unknown keys {extra}; expected some of {sorted(allowed)}')


def gin_literal(value) -> str:
  """A TOML value as a gin literal: True/False, numbers, quoted strings, [lists]."""
  if isinstance(value, bool):
    return str(value)
  if isinstance(value, (int, float)):
    return repr(value)
  if isinstance(value, str):
    return repr(value)
  if isinstance(value, list):
    return '[' + ', '.join(map(gin_literal, value)) + ']'
  raise TypeError(f'{value!r} cannot be a gin value')


def _number(value) -> Optional[float]:
  """value as a float if it is a real number (not a bool), else None."""
  return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def _axis(r: _Reader, table: dict, where: str) -> Axis:
  """An [[axis]] entry: binding + values, or explicit points."""
  r.unknown(table, ('name', 'binding', 'values', 'points'), where)
  name = r.get(table, 'name', where, str)
  if not name.isidentifier():
    r.fail(f'{where}.name', f'{name!r}; expected an identifier (it is a template field)')
  if ('binding' in table) == ('points' in table):
    r.fail(where, 'give either binding and values, or points')
  if 'binding' in table:
    binding = r.get(table, 'binding', where, str)
    values = r.get(table, 'values', where, list)
    try:
      points = [Point(str(v), _number(v), (f'{binding} = {gin_literal(v)}',)) for v in values]
    except TypeError as e:
      r.fail(f'{where}.values', str(e))
  else:
    points = []
    for i, p in enumerate(r.get(table, 'points', where, list)):
      at = f'{where}.points[{i}]'
      if not isinstance(p, dict):
        r.fail(at, f'{p!r}; expected a table {{label, value, bindings, configs}}')
      r.unknown(p, ('label', 'value', 'bindings', 'configs'), at)
      value = p.get('value')
      if value is not None and _number(value) is None:
        r.fail(f'{at}.value', f'{value!r}; expected a number')
      label = r.get(p, 'label', at, str, None) or (str(value) if value is not None else None)
      if label is None:
        r.fail(at, 'needs a label or a value')
      points.append(Point(label, _number(value), r.strings(p, 'bindings', at), r.strings(p, 'configs', at)))
  if not points:
    r.fail(where, 'has no points')
  labels = [p.label for p in points]
  bad = [l for l in labels if not l or '/' in l or '__' in l or l.startswith('.')]
  if bad or len(set(labels)) < len(labels):
    r.fail(where, f'labels {labels} must be distinct, non-empty, without "/" or "__"')
  return Axis(name, tuple(points))


def _names(r: _Reader, table: dict, key: str) -> dict:
  """A required table of named sub-tables (methods, scenes), names usable as folder names."""
  entries = r.get(table, key, '', dict)
  if not entries:
    r.fail(key, 'is empty')
  for name, entry in entries.items():
    if not isinstance(entry, dict):
      r.fail(f'{key}.{name}', f'{entry!r}; expected a table')
    if '/' in name or '__' in name or name.startswith('.') or '=' in name:
      r.fail(f'{key}.{name}', 'the name must not contain "/", "__", "=" or start with "."')
  return entries


def _budgets(r, plot_table: dict) -> Tuple[float, ...]:
  """[plot] budgets: positive training seconds, increasing."""
  budgets = r.get(plot_table, 'budgets', 'plot', list, [])
  if not all(isinstance(b, (int, float)) and not isinstance(b, bool) and b > 0 for b in budgets) or (
      sorted(budgets) != budgets):
    r.fail('plot.budgets', f'{budgets!r}; expected increasing positive numbers of training seconds')
  return tuple(float(b) for b in budgets)


def _paper(r: _Reader, entries: list, axes) -> Tuple[PaperCurve, ...]:
  curves = []
  for i, table in enumerate(entries):
    at = f'paper[{i}]'
    r.unknown(table, ('method', 'metric', 'x', 'points', 'source'), at)
    points = r.get(table, 'points', at, list)
    if not all(isinstance(p, list) and len(p) == 2 and all(_number(v) is not None for v in p) for p in points):
      r.fail(f'{at}.points', f'{points!r}; expected [[x, value], ...] numbers')
    curve = PaperCurve(method=r.get(table, 'method', at, str), metric=r.get(table, 'metric', at, str),
                       points=tuple((float(x), float(y)) for x, y in points), x=r.get(table, 'x', at, str),
                       source=r.get(table, 'source', at, str, ''))
    if curve.x not in axes:
      r.fail(f'{at}.x', f'{curve.x!r} is not an axis ({sorted(axes)})')
    curves.append(curve)
  return tuple(curves)


def _seed_axis(r: _Reader, data: dict) -> Tuple[Axis, ...]:
  """The seed axis of `seeds = N` or `seeds = [s, ...]` (none without the key)."""
  if 'seeds' not in data:
    return ()
  seeds = data['seeds']
  if isinstance(seeds, int) and not isinstance(seeds, bool):
    if seeds < 1:
      r.fail('seeds', f'{seeds}; expected a count >= 1 or a list of seeds')
    seeds = list(range(seeds))
  if (not isinstance(seeds, list) or not seeds or len(set(seeds)) < len(seeds)
      or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)):
    r.fail('seeds', f'{seeds!r}; expected a count >= 1 or a list of distinct integers >= 0')
  if any(a.get('name') == SEED_AXIS for a in data.get('axis', []) if isinstance(a, dict)):
    r.fail('seeds', f'the study also has an axis named {SEED_AXIS!r}; give one or the other')
  return (Axis(SEED_AXIS, tuple(Point(str(s), float(s), tuple(f'{b} = {s}' for b in SEED_BINDINGS))
                                for s in seeds)),)


def _looks(r: _Reader, data: dict, axes: Tuple[Axis, ...]) -> Tuple[int, ...]:
  """`looks`: increasing seed counts >= 1 at which the comparisons were read, the last the study's seed count."""
  if 'looks' not in data:
    return ()
  seeds = next((len(a.points) for a in axes if a.name == SEED_AXIS), None)
  if seeds is None:
    r.fail('looks', 'the study has no seeds; looks are the seed counts at which its comparisons were read')
  looks = data['looks']
  counts = isinstance(looks, list) and all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in looks)
  if not counts or not looks or sorted(set(looks)) != looks or looks[-1] != seeds:
    r.fail('looks', f'{looks!r}; expected increasing seed counts >= 1 at which the comparisons were read, the last '
                    f'the study\'s {seeds} seeds')
  return tuple(looks)


def _comparisons(r: _Reader, data: dict, study: Study) -> Tuple[Compare, ...]:
  """The [[compare]] entries, checked against the labels; default: every other method against the first."""
  labels = {'method': [m.name for m in study.methods], **{a.name: [p.label for p in a.points] for a in study.axes}}
  entries = r.get(data, 'compare', '', list, [])
  if not entries:
    return tuple(Compare('method', m.name, study.methods[0].name) for m in study.methods[1:])
  comparisons = []
  for i, table in enumerate(entries):
    at = f'compare[{i}]'
    if not isinstance(table, dict):
      r.fail(at, f'{table!r}; expected a table {{a, b, axis}}')
    r.unknown(table, ('a', 'b', 'axis'), at)
    axis = r.get(table, 'axis', at, str, 'method')
    if axis not in labels or axis == SEED_AXIS:
      r.fail(f'{at}.axis', f'{axis!r}; expected "method" or an axis other than the seed: {sorted(labels)}')
    a, b = r.get(table, 'a', at, str), r.get(table, 'b', at, str)
    for key, label in (('a', a), ('b', b)):
      if label not in labels[axis]:
        r.fail(f'{at}.{key}', f'{label!r} is not a label of {axis}: {labels[axis]}')
    if a == b:
      r.fail(at, f'a and b are both {a!r}')
    comparisons.append(Compare(axis, a, b))
  return tuple(comparisons)


def _evaluations(r: _Reader, data: dict) -> Tuple[Tuple[str, Tuple[str, ...]], ...]:
  """The [evaluations.<name>] tables: names usable as folder names and column suffixes, bookkeeping bindings."""
  entries = r.get(data, 'evaluations', '', dict, {})
  found = []
  for name, table in entries.items():
    where = f'evaluations.{name}'
    if not isinstance(table, dict):
      r.fail(where, f'{table!r}; expected a table {{bindings}}')
    if not name.isidentifier():
      r.fail(where, 'the name must be an identifier (a folder name and the suffix of its columns, <metric>@<name>)')
    r.unknown(table, ('bindings',), where)
    bindings = r.strings(table, 'bindings', where)
    if not bindings:
      r.fail(f'{where}.bindings', 'is empty; expected the settings this evaluation changes')
    study_evaluations.check_bindings(bindings, lambda message, at=f'{where}.bindings': r.fail(at, message))
    found.append((name, bindings))
  return tuple(found)


def _resources(r: _Reader, data: dict) -> Resources:
  """The [resources] table: num_gpus and num_cpus >= 0 (numbers), max_retries >= 0 (an integer)."""
  table = r.get(data, 'resources', '', dict, {})
  r.unknown(table, ('num_gpus', 'num_cpus', 'max_retries'), 'resources')
  values = {}
  for key, kind in (('num_gpus', (int, float)), ('num_cpus', (int, float)), ('max_retries', int)):
    value = table.get(key, getattr(Resources, key))
    if not isinstance(value, kind) or isinstance(value, bool) or not 0 <= value < float('inf'):
      r.fail(f'resources.{key}', f"{value!r}; expected {'an integer' if kind is int else 'a number'} >= 0")
    values[key] = value
  return Resources(**values)


def parse(text: str, path: str) -> Study:
  """The Study of a TOML text (path names it in errors)."""
  r = _Reader(path)
  try:
    data = tomllib.loads(text)
  except tomllib.TOMLDecodeError as e:
    raise StudyError(f'{path}: not valid TOML: {e}') from e
  r.unknown(data, ('name', 'description', 'bindings', 'methods', 'scenes', 'axis', 'seeds', 'looks', 'compare',
                   'plot', 'paper', 'resources', 'evaluations'), '')
  name = r.get(data, 'name', '', str)
  if not name or '/' in name or name.startswith('.'):
    r.fail('name', f'{name!r}; expected a folder name')
  methods = []
  for m, table in _names(r, data, 'methods').items():
    r.unknown(table, ('configs', 'bindings'), f'methods.{m}')
    methods.append(Method(m, r.strings(table, 'configs', f'methods.{m}'), r.strings(table, 'bindings', f'methods.{m}')))
  scenes = []
  for s, table in _names(r, data, 'scenes').items():
    r.unknown(table, ('bindings',), f'scenes.{s}')
    scenes.append((s, r.strings(table, 'bindings', f'scenes.{s}')))
  axes = tuple(_axis(r, a, f'axis[{i}]') for i, a in enumerate(r.get(data, 'axis', '', list, [])))
  axes += _seed_axis(r, data)
  axis_names = [a.name for a in axes]
  if len(set(axis_names)) < len(axis_names):
    r.fail('axis', f'axis names {axis_names} repeat')
  reserved = set(axis_names) & ({'out', 'data_root', 'study', 'method', 'scene', 'cell', 'status', 'step',
                                  'complete'} | set(RECORDED_X))
  if reserved:
    r.fail('axis', f'names {sorted(reserved)} are reserved (template fields or results.csv columns)')
  plot_table = r.get(data, 'plot', '', dict, {})
  r.unknown(plot_table, ('x', 'metrics', 'pareto', 'budgets'), 'plot')
  plot = Plot(r.strings(plot_table, 'x', 'plot') or tuple(axis_names[:1]),
              r.strings(plot_table, 'metrics', 'plot') or ('psnr',), r.get(plot_table, 'pareto', 'plot', bool, False),
              _budgets(r, plot_table))
  for x in plot.x:
    if x not in axis_names and x not in RECORDED_X:
      r.fail('plot.x', f'{x!r} is neither an axis {axis_names} nor a recorded value {list(RECORDED_X)}')
  study = Study(name, path, r.strings(data, 'bindings', ''), tuple(methods), tuple(scenes), axes, plot,
                _paper(r, r.get(data, 'paper', '', list, []), axis_names), resources=_resources(r, data),
                looks=_looks(r, data, axes), evaluations=_evaluations(r, data))
  study = dataclasses.replace(study, compare=_comparisons(r, data, study))
  _check_templates(study, r)
  return study


def load(path) -> Study:
  """Reads and validates a study file."""
  path = str(path)
  if not pathlib.Path(path).is_file():
    raise StudyError(f'study file {path!r} does not exist')
  return parse(pathlib.Path(path).read_text(), path)


def _fields(study: Study) -> set:
  return {'out', 'data_root', 'study', 'method', 'scene'} | {a.name for a in study.axes}


def _check_templates(study: Study, r: _Reader) -> None:
  """Every template field used in configs and bindings must be known (before any cell runs)."""
  known = _fields(study)
  texts = [('bindings', study.bindings)]
  texts += [(f'methods.{m.name}', m.configs + m.bindings) for m in study.methods]
  texts += [(f'scenes.{s}', b) for s, b in study.scenes]
  texts += [(f'axis {a.name}', p.configs + p.bindings) for a in study.axes for p in a.points]
  for where, strings in texts:
    for text in strings:
      try:
        used = {f for _, f, _, _ in string.Formatter().parse(text) if f is not None}
      except ValueError as e:
        r.fail(where, f'{text!r}: {e} (write {{{{ and }}}} for literal braces)')
      if used - known:
        r.fail(where, f'{text!r} uses unknown template fields {sorted(used - known)}; known: {sorted(known)}')


def cells(study: Study) -> List[Cell]:
  """Every cell: methods x scenes x axis points, in file order."""
  grids = list(itertools.product(*[[(a.name, p) for p in a.points] for a in study.axes]))
  return [Cell(study.name, m.name, s, tuple(g)) for m in study.methods for s, _ in study.scenes for g in grids]


def cell_gin(study: Study, cell: Cell, out: str, data_root: str, run_dir: str,
             extra_bindings=()) -> Tuple[List[str], List[str]]:
  """(gin config files, gin bindings) of a cell, templates filled, then extra_bindings, run dir and expname last."""
  method = next(m for m in study.methods if m.name == cell.method)
  scene = dict(study.scenes)[cell.scene]
  fields = dict(out=out, data_root=data_root, study=study.name, method=cell.method, scene=cell.scene,
                **cell.labels())
  fill = lambda texts: [t.format(**fields) for t in texts]
  points = [p for _, p in cell.points]
  configs = fill(method.configs + tuple(c for p in points for c in p.configs))
  bindings = fill(study.bindings + method.bindings + scene + tuple(b for p in points for b in p.bindings))
  return configs, bindings + list(extra_bindings) + [f'Config.expname = {cell.expname!r}', f'Config.checkpoint_dir = {run_dir!r}']


def write_cell_spec(folder: str, study: Study, cell: Cell, gin: Tuple[List[str], List[str]]) -> None:
  """Writes <folder>/cell_spec.json, atomically: the study, cell, method, scene and labels, and its gin (configs,
  bindings)."""
  written = {'study': study.name, 'cell': cell.cell_id, 'method': cell.method, 'scene': cell.scene,
             'labels': cell.labels(), 'gin_configs': gin[0], 'gin_bindings': gin[1]}
  atomic.write_text(os.path.join(folder, CELL_SPEC_FILE), json.dumps(written, indent=1))


def has_cell_spec(folder: str) -> bool:
  """Whether a cell's folder holds its cell_spec.json (a cell taken from an export has none)."""
  return os.path.isfile(os.path.join(folder, CELL_SPEC_FILE))


def read_cell_spec(folder: str) -> dict:
  """The cell_spec.json of a cell's folder; ValueError naming the file when it is missing or not one."""
  path = os.path.join(folder, CELL_SPEC_FILE)
  try:
    with open(path) as f:
      found = json.load(f)
  except FileNotFoundError:
    raise ValueError(f'{path}: does not exist; expected the cell_spec.json that lab.study writes into a cell\'s '
                     'folder before it runs (a cell taken from an export has none)') from None
  except (UnicodeDecodeError, json.JSONDecodeError) as e:
    raise ValueError(f'{path}: not valid JSON ({e}); expected the cell_spec.json that lab.study writes') from None
  if not isinstance(found, dict) or not {'gin_configs', 'gin_bindings'} <= set(found):
    raise ValueError(f'{path}: expected an object with "gin_configs" and "gin_bindings", as lab.study writes')
  return found


@contextlib.contextmanager
def cell_config(folder: str, extra_bindings=()) -> Iterator[runs.Config]:
  """runs.fresh_config of the gin a cell's folder records (its cell_spec.json), extra_bindings last."""
  found = read_cell_spec(folder)
  with runs.fresh_config(found['gin_configs'], found['gin_bindings'] + list(extra_bindings)) as config:
    yield config
