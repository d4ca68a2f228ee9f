"""Every number that the README, docs/ and the results READMEs state as a measurement is in a file that the command
which measured it wrote, at its place there: one home per number, compared token by token where the number is
written.

What is read (results/README.md, 'How the numbers are checked', says the same for authors):
- results/**/README.md: every measurement it states, against the data files in its folder and below it (CSV, JSON,
  JSONL, TSV, logs, and the Markdown that commands write: table.md, budgets.md, roofline.md, reports) and the
  files each paragraph links;
- README.md and docs/*.md: each paragraph, list item or table row that links a file under results/ (a folder: its
  README.md), or states a measurement (dB, PSNR, SSIM, LPIPS, a time, a percentage, a ratio such as 0.6x, a
  FLOP or byte count), against the files it links; one that links none is unbacked.

A measurement is a decimal number, both ends of a range (2.3-3.4x, [0.40, 0.70]), a ratio (0.6x), an integer with a
unit (421 s, 4 min 5 s, 95 %, 17 dB, 1656 passed, 77 photos). Left out: code (blocks and `spans`: settings), link
targets, versions (0.12.4, Python 3.11), settings named where they are given (T = 0.9 x steps, near 1.0, weight 0.1),
a table's first column (it names the row), dates, commits, and rough labels written with ~ (a budget of ~2 min).

Where a number may come from (its place):
- the files: a number with a link right after it is backed by that linked file alone; any other by the files its
  paragraph, list item or table row links and, in a results README, the files beside it;
- the record: a value belongs to a record (a CSV or Markdown table row, a JSON object, an export's cell, a log line,
  a Markdown paragraph). A record that has names (a row's text cells, a cell's method, scene and labels, less the
  words every record of its file shares) backs only numbers whose context names it: in a table row, the records of
  each file that the row's label (its cells before the first measurement, with the number's column header) names
  best, else one of whose names the row holds; in prose, one whose name the number's sentence holds (its paragraph
  where the sentence names none of the file's records). Names are compared loosely (`words`);
- the numbers written as one group, a value with its spread or interval (11.91 (1.59), +1.04 dB [-2.36, 4.43]) or
  slashed companions (8.09 / 0.364 / 0.526), are all in one record;
- a range (1.6-2.0 min) is the smallest and largest value of one field over the records that one name of its
  context names, where such a field holds its ends (in a table row whose label names records: either end);
- a learning curve's point (a row of a cell's learning_curve or a learning_curve.csv, a progress line of a training
  log) backs a number only where its unit states the step (19.46 dB at step 150), or as an end of a range that is the
  curve's extent, whole or between two steps stated (stays at 10.3-11.3 dB);
- a ratio (0.6x) is a value that a file states as a ratio (a number written with x, a field named ratio), or the
  quotient of two numbers of one kind that its unit states (0.6x the step time: 25.3 against 42.3 ms); a difference
  stated with 'by' may be theirs too (better by 1.0 dB: 11.35 against 10.34).
A value backs a number when, rounded to the digits stated, it gives the number: times compared in seconds,
percentages with fractions x 100, a number stated with dB, a time, % or a size only by a value of that kind (a JSON
key or CSV column naming psnr, seconds, ...; a Markdown number with that unit), a number stated without a sign by the
value's magnitude. Per-view values (metrics.json's per_image) back nothing.
"""

import csv
import functools
import io
import json
import math
import os
import re
import sys
from typing import List, NamedTuple, Optional

import pytest

from tools.study import cells_file

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, 'results')


def _documents() -> list:
  """README.md, docs/*.md and every README.md under results/, relative to the root."""
  docs = sorted(os.path.join('docs', n) for n in os.listdir(os.path.join(ROOT, 'docs')) if n.endswith('.md'))
  readmes = sorted(os.path.relpath(os.path.join(folder, 'README.md'), ROOT) for folder, _, names in os.walk(RESULTS)
                   if 'README.md' in names)
  return ['README.md'] + docs + readmes


DOCUMENTS = _documents()
LINK = re.compile(r'\]\(([^)#\s]+)(?:#[^)]*)?\)')
UNIT_BREAK = re.compile(r'\n\s*\n|\n(?=\s*- )|\n(?=\|)')
DATA_SUFFIXES = ('.csv', '.tsv', '.json', '.jsonl', '.md', '.log', '.txt')

# ---------------------------------------------------------------------------------------------- tokens


class Token(NamedTuple):
  """A number as written: its value in its own unit, its digits after the point, its kind of unit, the seconds or
  bytes per unit of a time or a size, whether a sign was written, and where it stands in its text."""
  value: float
  digits: int
  kind: Optional[str]   # 'dB' | 'time' | 'percent' | 'ratio' | 'bytes' | None
  seconds: Optional[float]
  signed: bool
  text: str
  start: int = 0
  end: int = 0


NUMBER = r'[+\-\u2212]?\d{1,3}(?:,\d{3})+(?:\.\d+)?|[+\-\u2212]?\d+(?:\.\d+)?'
# A whole token: not inside a word, a version (0.12.4), a path or an identifier (scan24, x86_64); 0.6x is a ratio.
TOKEN = re.compile(rf'(?<![\w.:/#@`])({NUMBER})(?=x\b|(?!\.\d|\.[a-z]|\w))')
UNITS = [(re.compile(r'\s?dB\b'), 'dB'), (re.compile(r'\s?(ms|s|min|minutes|seconds|h|hours)\b'), 'time'),
         (re.compile(r'\s?%'), 'percent'), (re.compile(r'x\b'), 'ratio'),
         (re.compile(r'\s?(KB|MB|GB|TB|KiB|MiB|GiB|TiB)\b'), 'bytes')]
# Per unit: seconds of a time, bytes of a size.
SCALES = {'ms': 1e-3, 's': 1., 'seconds': 1., 'min': 60., 'minutes': 60., 'h': 3600., 'hours': 3600.,
          'KB': 1e3, 'MB': 1e6, 'GB': 1e9, 'TB': 1e12, 'KiB': 2.**10, 'MiB': 2.**20, 'GiB': 2.**30, 'TiB': 2.**40}
COUNTS = re.compile(r'\s(photos|passed|skipped|failed|failures|registered)\b')
# Inside a range or list the unit follows the last number: '1.4-5 dB', '[0.40, 0.70] dB', '11.43, 11.00 dB', '28.7
# against 27.9 ms'.
RANGE_END = re.compile(rf'(\s?(?:-|\u2013|to|and|against|,|/)\s?\[?(?:{NUMBER})\]?)+')
COMPOSITE_TIME = re.compile(r'(?<![\w.])(\d+) (h|min) (\d+) (min|s)\b')
# Software whose version follows its name: 'Python 3.11', 'jax 0.11', 'COLMAP 3.8' are versions, not measurements.
SOFTWARE = r'Python|jax|jaxlib|COLMAP|CUDA|cuDNN|flax|optax|orbax|pycolmap|numpy|scipy|torch|Ray'
# A setting named where it is given: 'T = 0.9 x steps', 'M = 10', 'near 1.0', 'weight 0.1', 'gamma of 0.8', 'opacity
# 0.95', 'at 0.1 x the steps'.
SETTING = (r'\b(?:T|M|near|far|weight|gamma|opacity)(?: =| of)? [+-]?\d+(?:\.\d+)?(?: x (?:the )?steps)?\b'
           r'|\b\d+(?:\.\d+)? x (?:the )?steps\b')
SKIPPED = [re.compile(p, re.S | re.M) for p in (
    r'^ {4,}\S[^\n]*$', r'```.*?```', r'`[^`\n]*`', r'\]\([^)]*\)', r'<!--.*?-->',              # Code, link targets.
    r'\b\d{4}-\d{2}-\d{2}(T[\d:]+Z?)?\b', r'\b[0-9a-f]{7,40}\b',                           # Dates, commits.
    r'\d+(?:\.\d+)?% interval', r'\b(?:Table|Tables|Fig\.|Figure|Eq\.|issue|#)\s?\d+[a-z]?',
    r'~\s?\d+(?:[.-]\d+)*',                                                               # A rough label: ~2 min.
    rf'\b(?:{SOFTWARE}) \d+(?:\.\d+)+', r'\d+(?:\.\d+)?e-?\d+', SETTING)]


def _blank(text: str) -> str:
  """text with what states no measurement (code, link targets, dates, commits, ...) blanked out (by NUL characters,
  which neither indent a line nor join a number to a word)."""
  for pattern in SKIPPED:
    text = pattern.sub(lambda m: re.sub(r'[^\n]', '\0', m.group(0)), text)
  return text


def _unit(after: str):
  """(kind, seconds per unit) of the unit that follows a number (after a range or list), (None, None) if none."""
  end = RANGE_END.match(after)
  after = after[end.end():] if end else after
  for pattern, kind in UNITS:
    found = pattern.match(after)
    if found:
      return kind, SCALES.get(found.group(0).strip())
  return None, None


def tokens(text: str, every: bool = False) -> List[Token]:
  """The measurements a Markdown text states, in order: decimals, ratios, integers with a unit; '4 min 5 s' in
  seconds. every: bare integers too (what a data file holds)."""
  text = _blank(text)
  found = [Token(int(m.group(1)) * SCALES[m.group(2)] + int(m.group(3)) * SCALES[m.group(4)], 0, 'time', 1., False,
                 m.group(0), m.start(), m.end()) for m in COMPOSITE_TIME.finditer(text)]
  text = COMPOSITE_TIME.sub(lambda m: '\0' * len(m.group(0)), text)
  for m in TOKEN.finditer(text):
    number, after = m.group(1), text[m.end():]
    kind, seconds = _unit(after)
    decimal = '.' in number
    if not (every or decimal or kind or COUNTS.match(after)):
      continue  # A bare integer: a count of steps, views or seeds (a setting), not a measurement.
    signed = number[0] in '+-\u2212' and not (m.start() > 0 and text[m.start() - 1].isdigit())
    value = float(number.replace(',', '').replace('\u2212', '-'))
    found.append(Token(value if signed else abs(value), len(number.split('.')[1]) if decimal else 0, kind, seconds,
                       signed, number, m.start(1), m.end(1)))
  return sorted(found, key=lambda t: t.start)


def read_tokens(unit: str, header: str = '') -> List[Token]:
  """The tokens of a unit that the check reads: in a table row, those after its first column (which names the row)."""
  first = unit.find('|', unit.find('|') + 1) if header else -1
  return [t for t in tokens(unit) if t.start > first]


def token_spans(unit: str, header: str = '') -> list:
  """(start, end) of each number the check reads in a unit (for measuring what it catches)."""
  return [(t.start, t.end) for t in read_tokens(unit, header)]


def test_tokens_take_decimals_ranges_ratios_and_integers_with_units():
  text = ('FreeNeRF 12.5 dB against 6.3; 2.3-3.4x the floor, 0.6x the time; [0.40, 0.70] 95% interval; '
          'all 77 photos; 1656 passed in 882 s; 4 min 5 s; 1.8 min; 7% of pixels; -0.47 dB and +2.05; 3 views, '
          '2000 steps; orbax 0.12.4, commit 62ae429, 2026-11-26, scan24, `Config.x = 0.9`, [a](b_1.5.md), '
          'Table 5a, 5e-3, 11.43, 11.00 dB, Python 3.11. The end: 6.3.')
  got = [(t.text, t.kind, t.signed) for t in tokens(text)]
  assert got == [('12.5', 'dB', False), ('6.3', None, False), ('2.3', 'ratio', False),
                 ('3.4', 'ratio', False), ('0.6', 'ratio', False), ('0.40', None, False), ('0.70', None, False),
                 ('77', None, False), ('1656', None, False), ('882', 'time', False), ('4 min 5 s', 'time', False),
                 ('1.8', 'time', False), ('7', 'percent', False), ('-0.47', 'dB', True), ('+2.05', None, True),
                 ('11.43', 'dB', False), ('11.00', 'dB', False), ('6.3', None, False)]
  assert tokens('1.8 min')[0].seconds == 60. and tokens('4 min 5 s')[0].value == 245
  assert tokens('41 h 22 min')[0].value == 41 * 3600 + 22 * 60
  assert [text[t.start:t.end] for t in tokens(text)][:3] == ['12.5', '6.3', '2.3']


# ---------------------------------------------------------------------------------------------- data


class Value(NamedTuple):
  """A number of a data file, the kind its name gives it (a JSON key, a CSV column, a Markdown unit) and its field
  (that key or column; '' where none)."""
  value: float
  kind: Optional[str]
  field: str = ''


class Record(NamedTuple):
  """The numbers of one place of a data file: a table row, a JSON object, a log line, a Markdown paragraph; the
  names that tell it from the file's other places (a row's text cells, a cell's method, scene and labels), each as
  its words (a name's words shared by every record of the file left out). A learning curve's point has its step and
  the curve it belongs to (series)."""
  values: tuple
  where: str
  step: Optional[int] = None
  series: Optional[str] = None
  names: tuple = ()


# Names compared loosely: case, '-' within a word, '_' and letters from digits apart ('samples16' = '16 samples',
# 'mip-NeRF' = mipnerf), a plural's s; a table's 'object' PSNR is an export's psnr_masked, 'without' its 'no', degrees
# its deg.
SYNONYMS = {'object': 'mask', 'without': 'no', 'degree': 'deg', 'correlation': 'corr'}


def words(text: str) -> frozenset:
  """The words of a name or a context, as names are compared."""
  text = re.sub(r'(?<=[a-z])-(?=[a-z])|(?<=\b[a-z])_(?=[a-z])', '', text.lower())  # mip-NeRF, L_occ: one word.
  return frozenset(SYNONYMS.get(_stem(w), _stem(w)) for w in re.findall(r'[a-z]+|\d+', text))


def _stem(word: str) -> str:
  """A word without a plural's s or an ending -ing, -ed or -ment (ranking = rank, fixed = fix, refinement =
  refine)."""
  word = word[:-1] if len(word) > 3 and word.endswith('s') and not word.endswith('ss') else word
  return re.sub(r'(ing|ed|ment)$', '', word) if len(word) > 4 else word


def _names(texts) -> tuple:
  """The names that texts give: each part with a letter (a comparison 'rank1 - freenerf (method)' names both sides
  and its axis), as its words."""
  return tuple(words(part) for text in texts for part in re.split(r' - |[()]', text) if re.search('[A-Za-z]', part))


def _without_shared(records: List[Record]) -> List[Record]:
  """The records with their names cut to the words that tell them apart: the words every record of the file names
  left out, a name's numbers too where no other name has its other words (pearson01 is Pearson's; samples16 is not
  samples64), a name left with no word but numbers dropped; and a record, named by none, of the values that every
  named record holds (a column the same in every row is the file's)."""
  named = [r for r in records if r.names]
  shared = frozenset.intersection(*[frozenset().union(*r.names) for r in named]) if named else frozenset()
  letters = lambda name: frozenset(w for w in name if not w.isdigit())  # pylint: disable=unnecessary-lambda-assignment
  numbered = {}
  for name in {n - shared for r in named for n in r.names}:
    numbered.setdefault(letters(name), set()).add(name)
  cut = lambda name: name if len(numbered.get(letters(name), ())) > 1 else letters(name)  # pylint: disable=C3001
  found = [r._replace(names=tuple(cut(n - shared) for n in r.names if letters(n - shared))) for r in records]
  every = [v for v in (named[0].values if len(named) > 1 else ()) if all(v in r.values for r in named[1:])]
  return found + ([Record(tuple(every), f'{named[0].where.split(" ")[0]}, every row')] if every else [])


KIND_NAMES = [(re.compile(r'psnr|\bdb\b', re.I), 'dB'), (re.compile(r'second|seconds|\btime\b|_s\b|\bmin\b|\bms\b'
                                                                    r'|minutes', re.I), 'time'),
              (re.compile(r'pct|percent|within|%|coverage', re.I), 'percent'), (re.compile(r'bytes', re.I), 'bytes'),
              (re.compile(r'ratio|speedup|step / floor', re.I), 'ratio')]
NAME_SECONDS = [(re.compile(r'\bms\b|_ms\b', re.I), 1e-3), (re.compile(r'\bmin\b|minutes', re.I), 60.),
                (re.compile(r'\bhours?\b', re.I), 3600.)]


def _kind(name: str):
  """(kind, seconds per unit) that a value's name gives it ('95% interval' names no percentage)."""
  name = re.sub(r'\d+(?:\.\d+)?% interval', '', name)
  kind = next((k for pattern, k in KIND_NAMES if pattern.search(name)), None)
  scale = next((s for pattern, s in NAME_SECONDS if pattern.search(name)), 1.) if kind == 'time' else None
  return kind, scale


def _named(value, name: str, field: Optional[str] = None) -> Value:
  kind, scale = _kind(name)
  return Value(float(value) * (scale or 1.), kind, name if field is None else field)


def _stated(token: Token) -> Value:
  """A token of a data file as a value (times in seconds)."""
  return Value(token.value * (token.seconds or 1.), token.kind)


def _is_number(text: str) -> bool:
  try:
    return math.isfinite(float(text))
  except ValueError:
    return False


def _json_records(node, name: str, where: str, names: tuple = ()) -> List[Record]:
  """The records of a JSON value: each object's numbers (numbers written as strings and in its keys too: 'sphere 1
  (r 0.39)'), named by their key paths, the object named by its strings without spaces and its parents'; each list
  of numbers inside a list (a table's rows) a record of its own; per_image left out."""
  if isinstance(node, list):
    if node and all(isinstance(row, list) for row in node):
      return [Record(tuple(_named(v, name) for v in row if _is_json_number(v)), f'{where} {name} row {i + 1}',
                     names=names) for i, row in enumerate(node)]
    found = [r for child in node if isinstance(child, (dict, list)) for r in _json_records(child, name, where, names)]
    own = [_named(v, name) for v in node if _is_json_number(v)]
    return found + ([Record(tuple(own), f'{where} {name}', names=names)] if own else [])
  if not isinstance(node, dict):
    return []
  names = names + _names(v for v in node.values() if isinstance(v, str) and len(v) < 80 and not re.search(r'\s', v))
  own, found = [], []
  for key, child in node.items():
    if key == 'per_image':
      continue
    own += [_stated(t) for t in tokens(key, every=True)]
    path = f'{name}.{key}'
    if isinstance(child, (dict, list)):
      found += _json_records(child, path, where, names)
    elif _is_json_number(child):
      own.append(_named(child, path))
    elif isinstance(child, str) and len(child) < 400:
      own += [_stated(t) for t in tokens(child, every=True)]
  return ([Record(tuple(own), f'{where} {name or "(top)"}', names=names)] if own else []) + found


def _is_json_number(value) -> bool:
  if isinstance(value, bool) or value is None:
    return False
  if isinstance(value, (int, float)):
    return math.isfinite(value)
  return isinstance(value, str) and _is_number(value)


def _curve_records(curve: dict, where: str, names: tuple = ()) -> List[Record]:
  """A learning curve's points ({"columns", "rows"}): one record each, with its step and its curve."""
  columns = curve.get('columns') or []
  step = columns.index('step') if 'step' in columns else None
  return [Record(tuple(_named(v, c) for c, v in zip(columns, row) if _is_json_number(v)), f'{where} step {row[step]}',
                 int(row[step]) if step is not None else None, where, names)
          for row in curve.get('rows') or []]


def _cells_records(folder: str, path: str) -> List[Record]:
  """The records of an export's cells.jsonl (a reference to another export's line reads that line): each line's
  objects, its learning curve's points apart."""
  found = []
  for cell, entry in cells_file.read(folder).items():
    line = {k: v for k, v in entry.line.items() if k not in ('learning_curve', 'spec')}
    where = f'{os.path.relpath(path, ROOT)} cell {cell}'
    names = _names(re.split('__|=', cell))  # Its method, scene and labels.
    found += [r._replace(names=names) for r in _json_records(line, '', where)]
    if 'learning_curve' in entry.line:
      found += _curve_records(entry.line['learning_curve'], f'{where} learning curve', names)
  return found


def _csv_records(text: str, delimiter: str, where: str) -> List[Record]:
  """A CSV's rows, each number named by its column and its row's words (e.g. a comparison's metric), the numbers of
  its text cells too; the rows of a learning_curve.csv are its curve's points."""
  rows = list(csv.reader(io.StringIO(text), delimiter=delimiter))
  if not rows:
    return []
  if os.path.basename(where).startswith('learning_curve'):
    return _curve_records({'columns': rows[0], 'rows': [[float(v) if _is_number(v) else v for v in row]
                                                         for row in rows[1:]]}, where)
  found = []
  for number, row in enumerate(rows[1:], 2):
    texts = [c for c in row if not _is_number(c)]
    values = [_named(cell, f'{header} {" ".join(texts)}', header) for header, cell in zip(rows[0], row)
              if _is_number(cell)]
    values += [_stated(t) for text in texts for t in tokens(text, every=True)]  # 'with 10% of the bands visible'
    found.append(Record(tuple(values), f'{where} line {number}', names=_names(texts)))
  return found


def _markdown_records(text: str, where: str) -> List[Record]:
  """The records of a Markdown text: each table row (a cell's column header names its kind too; its text cells
  name it, in a README only its short ones) and each paragraph or list item."""
  readme = os.path.basename(where) == 'README.md'
  found, header = [], None
  for number, line in enumerate(text.splitlines(), 1):
    if not line.startswith('|'):
      header = None
      continue
    cells = [c.strip() for c in line.strip().strip('|').split('|')]
    if set(line) <= set('|-: '):
      continue
    if header is None:
      header, table = cells, number
      continue
    values = []
    for name, cell in zip(header, cells):  # A field: the table, its column, the number's place in the cell.
      kind, scale = _kind(name)
      values += [(_stated(t) if t.kind else Value(t.value * (scale or 1.), kind))._replace(field=f'{table}:{name}#{i}')
                 for i, t in enumerate(tokens(cell, every=True))]
    named = [c for c in cells if len(c) <= 24 and not tokens(c)] if readme else cells
    found.append(Record(tuple(values), f'{where} line {number}', names=_names(named)))
  for start, unit in units(text):
    if not unit.lstrip().startswith('|'):
      found.append(Record(tuple(_stated(t) for t in tokens(unit, every=True)),
                          f'{where} line {text.count(chr(10), 0, start) + 1}'))
  return found


LOOSE = re.compile(r'(?<![\w.])[+-]?\d+(?:\.\d+)?')
CLOCK = re.compile(r'(?<![\d:])(\d+):(\d\d)(?::(\d\d))?(?![\d:])')


PROGRESS = re.compile(r'(?<![\d/])(\d+)/(\d+) \[')  # A progress bar's 'step/steps [': a training curve's point.


def _log_records(text: str, where: str) -> List[Record]:
  """A log's lines: every number of each, units glued on or not (26.83step/s; after an x a ratio: 'step x 1.88'), its
  measurements with units (41 h 22 min), and its clock times (02:04) in seconds; a progress bar's line is a point of
  the run's curve at its step (its last step: the run's end, not a point)."""
  found = []
  for number, line in enumerate(text.splitlines(), 1):
    bar = PROGRESS.search(line)
    step = int(bar.group(1)) if bar and bar.group(1) != bar.group(2) else None
    values = [Value(float(m.group(0)), 'ratio' if re.search(r'x\s?$', line[:m.start()]) else None)
              for m in LOOSE.finditer(line)] + [_stated(t) for t in tokens(line)]
    for m in CLOCK.finditer(line):
      parts = [int(p) for p in m.groups() if p is not None]
      values.append(Value(float(sum(p * 60 ** (len(parts) - 1 - i) for i, p in enumerate(parts))), 'time'))
    if values:
      found.append(Record(tuple(values), f'{where} line {number}', step, where if step is not None else None))
  return found


@functools.lru_cache(maxsize=None)
def data_records(path: str) -> tuple:
  """The records of a data file under results/ (a README: the measurements it states, by paragraph and row)."""
  return tuple(_without_shared(_file_records(path)))


def _file_records(path: str) -> List[Record]:
  where = os.path.relpath(path, ROOT)
  if path.endswith('.jsonl'):
    return _cells_records(os.path.dirname(path), path)
  with open(path, errors='replace') as f:
    text = f.read()
  if path.endswith('.json'):
    return _json_records(json.loads(text), '', where)
  if path.endswith(('.csv', '.tsv')):
    return _csv_records(text, '\t' if path.endswith('.tsv') else ',', where)
  if path.endswith(('.log', '.txt')):
    return _log_records(text, where)
  return _markdown_records(text, where)


# ---------------------------------------------------------------------------------------------- places


def _data_files(folder: str) -> list:
  """The data files of a folder, and of its subfolders that have no README.md of their own (theirs speak for
  them), its own README.md left out."""
  found = []
  for name in sorted(os.listdir(folder)):
    path = os.path.join(folder, name)
    if os.path.isdir(path) and not os.path.isfile(os.path.join(path, 'README.md')):
      found += _data_files(path)
    elif name.endswith(DATA_SUFFIXES) and name != 'README.md':
      found.append(path)
  return found


def _linked_file(link: str, document: str) -> Optional[str]:
  """The data file under results/ that a link of a document names (a folder: its README.md), None if none."""
  path = os.path.normpath(os.path.join(ROOT, os.path.dirname(document), link))
  path = os.path.join(path, 'README.md') if os.path.isdir(path) else path
  if path.startswith(RESULTS + os.sep) and os.path.isfile(path) and path.endswith(DATA_SUFFIXES):
    return path
  return None


def linked_files(unit: str, document: str) -> list:
  """The files under results/ that a unit links (a folder: its README.md), as absolute paths."""
  return [p for p in (_linked_file(link, document) for link in LINK.findall(unit)) if p]


def beside(document: str) -> list:
  """The data files a results README sits among ([] for README.md and docs/)."""
  path = os.path.join(ROOT, document)
  return _data_files(os.path.dirname(path)) if path.startswith(RESULTS + os.sep) else []


# What may stand between a number (its group) and the link that names its file: a unit, brackets, punctuation.
LINK_AFTER = re.compile(r'[\s*,:;()\[\]]*(?:dB|%|ms|s|min|x|MiB|GiB)?[\s*,:;()]*\[[^\]]*\]\(([^)#\s]+)')


def _sources(unit: str, end: int, document: str, every: list) -> list:
  """The files a number (a group ending at end) may come from: the data file of a link right after it, else every
  file of its unit (its links and, in a results README, the files beside it)."""
  found = LINK_AFTER.match(unit, end)
  path = found and _linked_file(found.group(1), document)
  return [path] if path else every


# What joins the numbers of one group: a unit, then an opening bracket or +- ('11.91 (1.59)', '+1.04 dB [-2.36,
# 4.43]', '11.82 +- 2.18'), or a comma inside the bracket; bold marks around them. A slash joins groups that one
# record holds where one holds two of them ('8.09 / 0.364 / 0.526', a run's PSNR, SSIM and LPIPS), each on its own
# where none does ('11.82 +- 2.18 / 11.52 +- 2.39', two rows of a summary).
GROUP_OPEN = re.compile(r'^\**\s?(?:dB|%|ms|s|min|x|MiB|GiB|degrees)?\s?\**\s?(?:\(|\[|\+-|\u00b1)\s?\**$')
GROUP_INSIDE = re.compile(r'^\**,\s?\**$')
GROUP_SLASH = re.compile(r'^\**\s?(?:dB|%|ms|s|min|x|MiB|GiB|degrees)?\s?\**\s?/\s?\**$')


# A bracket that holds a spread or an interval holds nothing but numbers: '(1.59)', '[-2.36, 4.43]'.
BRACKETED = re.compile(r'[(\[][\s\d.,+\-\u2212*%]*(?:dB|ms|s|min|x|MiB|GiB|degrees)?[\s*]*[)\]]')


def groups(unit: str, found: List[Token]) -> List[List[List[Token]]]:
  """The tokens of a unit in groups, each a list of parts joined by slashes; a part is a value with its spread or
  interval, or a token alone."""
  grouped, inside = [], False
  for token in found:
    between = unit[grouped[-1][-1][-1].end:token.start] if grouped else ''
    opens = GROUP_OPEN.match(between)
    if opens and between.rstrip('* ').endswith(('(', '[')):
      opens = BRACKETED.match(unit, grouped[-1][-1][-1].end + max(between.rfind('('), between.rfind('[')))
    if grouped and opens:
      grouped[-1][-1].append(token)
      inside = between.rstrip('* ').endswith(('(', '['))
    elif grouped and inside and GROUP_INSIDE.match(between):
      grouped[-1][-1].append(token)
    elif grouped and GROUP_SLASH.match(between):
      grouped[-1].append([token])
      inside = False
    else:
      grouped.append([[token]])
      inside = False
  return grouped


def test_groups_join_a_value_with_its_spread_interval_or_slashed_companions():
  unit = ('16 samples 11.91 (1.59), +1.04 dB [-2.36, 4.43], 8.09 / **0.364** / 0.526 | 3.8-4.1; 60, 120 and 480 s; '
          '12.5 dB against 6.3; 11.82 +- 2.18 / 11.52 +- 2.39')
  assert [[[t.text for t in p] for p in g] for g in groups(unit, tokens(unit))] == [
      [['11.91', '1.59']], [['+1.04', '-2.36', '4.43']], [['8.09'], ['0.364'], ['0.526']], [['3.8']], [['4.1']],
      [['60']], [['120']], [['480']], [['12.5']], [['6.3']], [['11.82', '2.18'], ['11.52', '2.39']]]


def _kin(token: Token, value: Value) -> bool:
  """Whether a value may back a token: a token stated in dB, a time, a percentage or a size only by a value of that
  kind or of none (a whole number of none only a whole number: a count is no 3.0 min), a ratio only by a ratio."""
  if token.kind == 'ratio':
    return value.kind == 'ratio'
  if token.kind not in ('dB', 'time', 'percent', 'bytes') or value.kind == token.kind:
    return True
  return value.kind is None and not (token.digits and float(value.value).is_integer())


def gives(token: Token, value: Value) -> bool:
  """Whether a value, rounded to the digits stated, gives the token (by magnitude when no sign is written)."""
  if not _kin(token, value):
    return False
  stated = f'{token.value:.{token.digits}f}'
  number = value.value if token.signed else abs(value.value)
  candidates = [number]
  if token.kind in ('time', 'bytes'):  # Seconds or bytes; a value of no kind may be in the unit stated.
    candidates = [number / (token.seconds or 1.)] + ([number] if value.kind is None else [])
  elif token.kind == 'percent':
    candidates.append(number * 100.)
  return any(f'{c:.{token.digits}f}' == stated for c in candidates)


def backed(token: Token, values) -> bool:
  """Whether any of the values gives the token."""
  return any(gives(token, v) for v in values)


def _steps_stated(unit: str) -> set:
  """The integers a unit states (the steps a learning curve's point may be named by)."""
  return {int(n.replace(',', '')) for n in re.findall(r'(?<![\w.])\d{1,3}(?:,\d{3})+(?![\w.])|(?<![\w.])\d+(?![\w.])',
                                                      unit)}


def _placed(records: list, steps: Optional[set], nears: tuple, labels: tuple = ()) -> list:
  """The records that may back numbers whose context has the words nears (nearest first): of the records that have
  names, those that the nearest context naming one of the file's names names, and in a table row, of each file's,
  those its label (first cell and
  column header; the cell's words before a bracket first) names best (the most words of their names) where it names
  any; a README's rows all where the context names none; a learning curve's point only where its step is stated
  (steps None: every point)."""
  records = [r for r in records if steps is None or r.step is None or r.step in steps]
  label = next((l for l in labels if any(_named_by(r, l) for r in records)), frozenset())
  near = {}
  for path in {_file(r) for r in records}:
    near[path] = next((n for n in nears if any(m <= n for r in records if _file(r) == path for m in r.names)),
                      nears[-1])
  best, unnamed = {}, set()
  for r in records:  # A README's rows are named loosely (its short cells): its context names them, if any.
    best[_file(r)] = 0 if _file(r).endswith('README.md') else max(best.get(_file(r), 0), _named_by(r, label))
  for path in {_file(r) for r in records if _file(r).endswith('README.md')}:
    if not any(n <= near[path] for r in records if _file(r) == path for n in r.names):
      unnamed.add(path)
  return [r for r in records if not r.names or _file(r) in unnamed or (
      _named_by(r, label) == best[_file(r)] if best[_file(r)] else any(n <= near[_file(r)] for n in r.names))]


def _named_by(record: Record, label: frozenset) -> int:
  """How much of a record a label names: the words of its names that the label holds whole."""
  return sum(len(n) for n in record.names if n <= label)


def _file(record: Record) -> str:
  return record.where.split(' ')[0].rstrip(',')


def _extent(low: Token, high: Token, placed: list, near: frozenset, row: bool) -> bool:
  """Whether a range's ends are the smallest and largest value of one field over the records at its place that one
  name its context holds names, where such a field holds both ends (in a table row whose label names records:
  either end); else whether each
  end is a value at its place (a range over records its context does not name apart, or read off a README)."""
  groups = {}
  for record in (r for r in placed if not _file(r).endswith('README.md')):  # A README's rows: loosely named.
    for name in [n for n in record.names if n <= near]:
      for value in record.values:
        if value.field:
          groups.setdefault((_file(record), value.field, name), []).append(value)
  holds = (lambda v: backed(low, v) or backed(high, v)) if row else (lambda v: backed(low, v) and backed(high, v))
  holding = [v for v in groups.values() if holds(v)]
  if not holding:
    return any(backed(low, r.values) for r in placed) and any(backed(high, r.values) for r in placed)
  return any(gives(low, min(v, key=lambda x: x.value)) and gives(high, max(v, key=lambda x: x.value))
             for v in holding)

CLAUSE_END = re.compile(r'\.\s')


def _near(unit: str, header: str, token: Token) -> tuple:
  """The words that name the place of a number, nearest first: a table row's with its column's header; else its
  sentence, then its paragraph or list item."""
  if header:
    column = unit[:token.start].count('|') - 1
    names = [c.strip() for c in header.strip().strip('|').split('|')]
    return (words(' '.join([unit] + names[column:column + 1])),)
  start = max([m.end() for m in CLAUSE_END.finditer(unit, 0, token.start)] or [0])
  end = CLAUSE_END.search(unit, token.end)
  return words(unit[start:end.start() if end else len(unit)]), words(unit)


def _label(unit: str, header: str, token: Token) -> tuple:
  """The words of a table row's label, its cells before its first measurement, with its number's column header, most
  telling first: the label's `code` (a cell's id: `batch512`), its cells each before its first bracket, the whole
  label; () outside a table."""
  if not header:
    return ()
  column = unit[:token.start].count('|') - 1
  names = [c.strip() for c in header.strip().strip('|').split('|')]
  cells = unit.strip().strip('|').split('|')
  lead = cells[:next((i for i, c in enumerate(cells[1:], 1) if tokens(c)), len(cells))]
  named = ' '.join(names[column:column + 1])
  code = ' '.join(re.findall(r'`([^`]*)`', ' '.join(lead)))
  heads = ' '.join(c.split('(')[0] for c in lead)
  return tuple(words(part + ' ' + named) for part in ([code] if code else []) + [heads, ' '.join(lead)])


def _headed(found: List[Token], unit: str, header: str) -> List[Token]:
  """The tokens of a table row, each without a unit of its own given its column header's ('step ms', 'train min',
  'object PSNR')."""
  if not header or not unit.lstrip().startswith('|'):
    return found
  names = [c.strip() for c in header.strip().strip('|').split('|')]
  bounds = [m.start() for m in re.finditer(r'\|', unit)]
  headed = []
  for token in found:
    column = sum(b < token.start for b in bounds) - 1
    kind, scale = _kind(names[column]) if 0 <= column < len(names) else (None, None)
    if token.kind is None and kind and not COUNTS.match(unit[token.end:]):
      token = token._replace(kind=kind, seconds=scale if kind == 'time' else None)
    headed.append(token)
  return headed


def _curve_extent(token: Token, other: Token, records: list, near: tuple, steps: set) -> bool:
  """Whether two ends of a range are the smallest and largest value of one learning curve's field, over the whole
  curve or between two steps its unit states ('18.5-18.8 dB from step 2500 to 7000')."""
  by_series = {}
  for record in _placed(records, None, near):
    if record.series is not None:
      by_series.setdefault(record.series, []).append(record)
  for points in by_series.values():
    stated = sorted(p.step for p in points if p.step in steps)
    windows = [points] + [[p for p in points if a <= p.step <= b] for a in stated for b in stated if a < b]
    for window in windows:
      for column in range(min(len(p.values) for p in window)):
        values = [p.values[column] for p in window]
        low, high = min(values, key=lambda v: v.value), max(values, key=lambda v: v.value)
        if (gives(token, low) and gives(other, high)) or (gives(token, high) and gives(other, low)):
          return True
  return False


RANGE_JOIN = re.compile(r'^(?:-|\u2013)$')


def _range_partner(unit: str, found: List[Token], token: Token) -> Optional[Token]:
  """The other end of the range a token is an end of ('10.3-11.3'), None if it is none."""
  index = found.index(token)
  for other in (found[index - 1] if index else None, found[index + 1] if index + 1 < len(found) else None):
    if other is not None:
      first, second = sorted((token, other), key=lambda t: t.start)
      if RANGE_JOIN.match(unit[first.end:second.start]):
        return other
  return None


def _computed(token: Token, found: List[Token], unit: str) -> bool:
  """Whether two other numbers of the unit, of one kind (or one written without its unit: '25.3 against 42.3 ms'),
  give the token: a ratio as their quotient, a difference stated with 'by' (better by 1.0 dB) as a - b."""
  difference = re.search(r'\bby\s$', unit[:token.start]) and token.kind in ('dB', None)
  if token.kind != 'ratio' and not difference:
    return False
  stated = f'{token.value:.{token.digits}f}'
  numbers = [t for t in found if t is not token and t.kind != 'ratio' and t.value]
  for a in numbers:
    for b in numbers:
      if a is not b and (a.kind == b.kind or None in (a.kind, b.kind)):
        scale = (a.seconds or 1.) / (b.seconds or 1.) if a.kind == b.kind else 1.
        got = a.value - b.value if difference else a.value / b.value * scale
        if f'{got if token.signed else abs(got):.{token.digits}f}' == stated:
          return True
  return False


def _group_backed(group: List[Token], placed: list) -> bool:
  """Whether one record at the group's place holds every number of the group."""
  return any(all(backed(t, r.values) for t in group) for r in placed)


def _records(files: list) -> list:
  return [r for f in files for r in data_records(f)]


def _explain(group: List[Token], records: list) -> str:
  """What the check found for an unbacked group: where its numbers are (not at their place), or that no file has
  them."""
  if not records:
    return 'its unit links no file under results/ and no file sits beside it'
  places = [r for r in records if any(backed(t, r.values) for t in group)][:3]
  files = sorted({r.where.split(' ')[0] for r in records})
  if places:
    together = f' (together: {" ".join(t.text for t in group)})' if len(group) > 1 else ''
    return (f'expected at its place{together}; found only at ' + '; '.join(
        r.where + (f' (step {r.step}, not stated)' if r.step is not None else '') +
        (f' (named {" or ".join(" ".join(sorted(n)) for n in r.names)}, not here)' if r.names else '')
        for r in places))
  return f'no value of {", ".join(files[:4])}{" ..." if len(files) > 4 else ""} gives it'


def _unit_is_read(unit: str, linked: list, around: list) -> bool:
  return bool(linked or around or MEASURED.search(_blank(unit)))


MEASURED = re.compile(r'\d\s?(dB|%|x\b|ms\b|s\b|min\b|GB\b|MB\b)|PSNR|SSIM|LPIPS|FLOP|steps/s|rays/s')


def unit_problems(unit: str, document: str, header: str = '') -> list:
  """[(number as written, why)] of the numbers of one unit (a table row: with its table's header) that no value at
  their place backs."""
  around = beside(document)
  linked = linked_files(unit, document)
  if not _unit_is_read(unit, linked, around):
    return []
  found, steps, problems = _headed(read_tokens(unit, header), unit, header), _steps_stated(unit + ' ' + header), []
  every = linked + around
  for joined in groups(unit, found):
    records = _records(_sources(unit, joined[-1][-1].end, document, every))
    near = _near(unit, header, joined[0][0])
    placed = _placed(records, steps, near, _label(unit, header, joined[0][0]))
    partner = _range_partner(unit, found, joined[0][0]) if len(joined) == len(joined[0]) == 1 else None
    if partner is not None:  # A range: the extent of a field over the records its context names.
      low, high = sorted((joined[0][0], partner), key=lambda t: t.start)
      labelled = any(_named_by(r, l) for r in records for l in _label(unit, header, low))
      if not (_extent(low, high, placed, near[-1], labelled) or _curve_extent(low, high, records, near, steps)):
        problems.append((joined[0][0].text, f'expected {low.text}-{high.text} to be the smallest and largest value '
                                            'of one field over the records its context names'))
      continue
    if _group_backed([t for part in joined for t in part], placed):
      continue
    if any(sum(all(backed(t, r.values) for t in part) for part in joined) > 1 for r in placed):
      problems += [(t.text, _explain([t for part in joined for t in part], placed)) for part in joined for t in part]
      continue  # A record holds two of its slashed parts: it is their record, and it lacks the others.
    for group in joined:
      if _group_backed(group, placed):
        continue
      if len(group) == 1 and _computed(group[0], found, unit):
        continue
      problems += [(t.text, _explain(group, records)) for t in group]
  return problems


def units(markdown: str) -> list:
  """[(offset, text)] of the paragraphs, list items and table rows of a Markdown text, code blocks left out."""
  text = re.sub(r'```.*?```', lambda m: re.sub(r'[^\n]', '\0', m.group(0)), markdown, flags=re.S)
  found, start = [], 0
  for m in UNIT_BREAK.finditer(text):
    found.append((start, text[start:m.start()]))
    start = m.end()
  return found + [(start, text[start:])]


def headed_units(markdown: str) -> list:
  """[(offset, text, its table's header row or '')] of the units of a Markdown text; a table's header row, which
  names its columns ('within 5%'), is left out."""
  found, header = [], ''
  for start, unit in units(markdown):
    row = unit.lstrip().startswith('|')
    header = (header or unit) if row else ''
    if not (row and unit is header):
      found.append((start, unit, header if row else ''))
  return found


def unbacked(markdown: str, document: str) -> list:
  """[(line, number as written, why)] of the measurements a document states that no value at their place backs."""
  return [(markdown.count('\n', 0, start) + 1, number, why) for start, unit, header in headed_units(markdown)
          for number, why in unit_problems(unit, document, header)]


def _read(document: str) -> str:
  with open(os.path.join(ROOT, document)) as f:
    return f.read()


@pytest.mark.parametrize('document', DOCUMENTS)
def test_every_measurement_is_at_its_place_in_a_file_beside_or_linked(document):
  missing = unbacked(_read(document), document)
  assert not missing, f'{document}: numbers that no value at their place backs:\n' + '\n'.join(
      f'  line {line}: {number}: {why}' for line, number, why in missing)


def test_a_number_is_compared_at_the_digits_stated_and_by_kind():
  values = [Value(12.4981, 'dB'), Value(0.6049, None), Value(421.3, 'time'), Value(0.071, 'percent'),
            Value(-0.47, None), Value(108.2, 'time'), Value(3.3, 'time'), Value(0.6, 'ratio')]
  ok = ('FreeNeRF 12.5 dB and 12.50 dB and 12.498 dB; 0.60 and 0.6x; 7 min 1 s; 7% of pixels; 0.47 dB; -0.47; '
        '1.8 min; 421 s; 3.3 s')
  assert [t.text for t in tokens(ok) if not backed(t, values)] == []
  wrong = 'FreeNeRF 12.4 dB; 12.49 dB; 0.61; 7 min 2 s; 8% of pixels; +0.47; 1.9 min; 3.3 dB; 421.3 min; 0.5x'
  assert [t.text for t in tokens(wrong) if not backed(t, values)] == [
      '12.4', '12.49', '0.61', '7 min 2 s', '8', '+0.47', '1.9', '3.3', '421.3', '0.5']
  assert not backed(tokens('0.6x')[0], [Value(0.6, None)])  # A ratio only by a ratio.


def _export(tmp_path, cells_csv: str, curve_rows: list):
  """A results folder with a summary CSV and a cells.jsonl whose one cell has a learning curve."""
  folder = tmp_path / 'results' / 'x'
  folder.mkdir(parents=True)
  (folder / 'summary.csv').write_text(cells_csv)
  line = {'cell': 'a', 'record': {'means': {'psnr': 11.0}}, 'learning_curve': {'columns': ['step', 'psnr'],
                                                                             'rows': curve_rows}}
  (folder / 'cells.jsonl').write_text(json.dumps(line) + '\n')
  (folder / 'provenance.json').write_text('{}')
  return folder


def test_a_number_is_backed_only_at_its_place(tmp_path, monkeypatch):
  folder = _export(tmp_path, 'variant,metric,mean,std\nbase,psnr,10.87,1.27\nwide,psnr,11.95,0.40\n',
                   [[100, 11.92], [200, 10.30], [300, 11.30]])
  monkeypatch.setattr(sys.modules[__name__], 'RESULTS', str(tmp_path / 'results'))
  monkeypatch.setattr(sys.modules[__name__], 'ROOT', str(tmp_path))
  document = os.path.relpath(folder / 'README.md', tmp_path)
  check = lambda text: [n for _, n, _ in unbacked(text, document)]  # pylint: disable=unnecessary-lambda-assignment
  table = '| variant | PSNR |\n|---|---|\n'
  right = '| base | 10.87 (1.27) |\n\nwide 11.95 (0.40); 11.92 dB at step 100; stays at 10.3-11.9 dB'
  assert check(table + right) == []
  assert check(table + '| base | 10.87 (0.40) |') == ['10.87', '0.40']  # Both numbers, but not in one row.
  assert check(table + '| base | 11.95 (0.40) |') == ['11.95', '0.40']  # In one row, but not the row named.
  assert check('the curve reached 11.92 dB') == ['11.92']             # A curve's point names its step.
  assert check('11.92 dB at step 200') == ['11.92']
  assert check('stays at 10.3-11.3 dB') == ['10.3', '11.3']           # Not the curve's extent.
  data_records.cache_clear()


def test_a_ratio_is_the_quotient_of_the_two_numbers_it_compares():
  ratios = lambda unit: [n for n, _ in unit_problems(unit, 'README.md') if n.startswith('0.')]  # pylint: disable=C3001
  assert ratios('at 0.6x the step time (25.3 against 42.3 ms)') == []
  assert ratios('at 0.7x the step time (25.3 against 42.3 ms)') == ['0.7']


# The substitutions that the substring match of an earlier check let through (issue 53), each in the README.
SUBSTITUTIONS = [('FreeNeRF 12.5 dB', 'FreeNeRF 12.4 dB'), ("mip-NeRF's 6.3", "mip-NeRF's 6.8"),
                 ('by 0.55 dB', 'by 0.5 dB'), ('2.3-3.4x', '2.3-9.9x'), ('all 77 photos', 'all 78 photos')]


@pytest.mark.parametrize('right, wrong', SUBSTITUTIONS)
def test_a_wrong_number_in_the_readme_is_found(right, wrong):
  text = _read('README.md')
  assert right in text, f'the README no longer says {right!r}'
  assert unbacked(text, 'README.md') == []
  found = [n for _, n, _ in unbacked(text.replace(right, wrong), 'README.md')]
  assert re.search(NUMBER, wrong.replace('2.3-', '')).group(0) in found and len(found) <= 2  # A range: both ends.


# Drifts found by recomputation (issue 53), each put back where it was fixed: the check finds it again.
DRIFTS = [('results/studies/speed_accuracy/README.md', '1000 steps -0.19 [-5.20, 4.82]',
           '1000 steps -0.19 [-4.82, 4.72]'),
          ('results/studies/xyz_ablation_mini/README.md', '+0.58 [-4.94, 6.09]', '+0.58 [-4.94, 6.10]'),
          ('results/studies/occlusion/README.md', '| M = 15 | 10.90 |', '| M = 15 | 10.91 |'),
          ('results/studies/README.md', '0.47 [-20.28, 21.21]', '0.47 [-3.31, 4.24]'),
          ('results/gpu/README.md', '10.2 GiB', '10.2 GB'),
          ('docs/running.md', 'took 24.2 s', 'took 67 s')]


@pytest.mark.parametrize('document, right, wrong', DRIFTS, ids=[d[2] for d in DRIFTS])
def test_a_drift_put_back_is_found(document, right, wrong):
  text = _read(document)
  assert right in text, f'{document} no longer says {right!r}'
  assert unbacked(text.replace(right, wrong), document), f'{wrong!r} in {document} passes'


def _mutants(written: str):
  """Each one-digit change of a number as written: a digit d becomes d + 1 (9 becomes 8)."""
  for i, digit in enumerate(written):
    if digit.isdigit():
      yield written[:i] + str(int(digit) + 1 if digit != '9' else 8) + written[i + 1:]


def catch_rate(document: str) -> tuple:
  """(caught, tried): the one-digit changes to the numbers the check reads in a document that it reports."""
  caught = tried = 0
  for _, unit, header in headed_units(_read(document)):
    before = unit_problems(unit, document, header)
    for start, end in token_spans(unit, header) if _unit_is_read(unit, linked_files(unit, document),
                                                                  beside(document)) else []:
      for changed in _mutants(unit[start:end]):
        tried += 1
        caught += unit_problems(unit[:start] + changed + unit[end:], document, header) != before
  return caught, tried


def test_one_digit_changes_to_the_speed_accuracy_readme_are_caught():
  caught, tried = catch_rate('results/studies/speed_accuracy/README.md')
  assert caught >= 0.95 * tried, f'caught {caught} of {tried} one-digit changes'


def _linked_readmes(path: str, seen: set) -> None:
  """Adds to seen every README.md under results/ reachable from path through Markdown links."""
  if path in seen or not os.path.isfile(path):
    return
  seen.add(path)
  with open(path) as f:
    targets = re.findall(r'\]\(([^)#\s]+)', f.read())
  for target in targets:
    linked = os.path.normpath(os.path.join(os.path.dirname(path), target))
    linked = os.path.join(linked, 'README.md') if os.path.isdir(linked) else linked
    if linked.startswith(RESULTS) and linked.endswith('README.md'):
      _linked_readmes(linked, seen)


def test_results_readme_reaches_every_results_readme():
  seen = set()
  _linked_readmes(os.path.join(RESULTS, 'README.md'), seen)
  every = {os.path.join(folder, 'README.md') for folder, _, names in os.walk(RESULTS) if 'README.md' in names}
  unreached = sorted(os.path.relpath(p, ROOT) for p in every - seen)
  assert not unreached, f'results/README.md links no path to {unreached}'


def test_every_study_export_has_a_readme():
  studies = os.path.join(RESULTS, 'studies')
  lacking = sorted(name for name in os.listdir(studies) if os.path.isdir(os.path.join(studies, name))
                   and not os.path.isfile(os.path.join(studies, name, 'README.md')))
  assert not lacking, f'study exports without a README.md (what was run, what it shows and what not): {lacking}'
