"""Every number that the README, docs/ and the results READMEs state as a measurement is in a file that the command
which measured it wrote: one home per number, compared token by token where the number is written.

What is checked (results/README.md, 'How the numbers are checked', says the same for authors):
- results/**/README.md: every measurement it states, against the data files in its folder and below it (CSV, JSON,
  JSONL, TSV, logs, and the Markdown that commands write: table.md, budgets.md, roofline.md, reports) and the
  files each paragraph links;
- README.md and docs/*.md: each paragraph, list item or table row that links a file under results/ (a folder: its
  README.md), or states a measurement (dB, PSNR, SSIM, LPIPS, a time, a percentage, a ratio such as 0.6x, a
  FLOP or byte count), against the files it links; one that links none is unbacked.

A measurement is a decimal number, both ends of a range (2.3-3.4x, [0.40, 0.70]), a ratio (0.6x), an integer with a
unit (421 s, 4 min 5 s, 95 %, 17 dB, 1656 passed, 77 photos). It is backed when a value of the files, rounded to the
digits stated, gives it: times compared in seconds, percentages with fractions x 100, a number stated with dB, a
time or % only with values of that kind (a JSON key or CSV column naming psnr, seconds, ...; a Markdown number with
that unit), a number stated without a sign with the value's magnitude. Per-view values (metrics.json's per_image)
back nothing. Left out: code (blocks and `spans`: settings), link targets, versions (0.12.4), dates, commits, and
rough labels written with ~ (a budget of ~2 min).
"""

import csv
import functools
import io
import json
import math
import os
import re
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
  bytes per unit of a time or a size, whether a sign was written."""
  value: float
  digits: int
  kind: Optional[str]   # 'dB' | 'time' | 'percent' | 'ratio' | 'bytes' | None
  seconds: Optional[float]
  signed: bool
  text: str


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
# Inside a range or list the unit follows the last number: '1.4-5 dB', '[0.40, 0.70] dB', '11.43, 11.00 dB'.
RANGE_END = re.compile(rf'(\s?(?:-|\u2013|to|and|,)\s?\[?(?:{NUMBER})\]?)+')
COMPOSITE_TIME = re.compile(r'(?<![\w.])(\d+) (h|min) (\d+) (min|s)\b')
SKIPPED = [re.compile(p, re.S | re.M) for p in (
    r'^ {4,}\S[^\n]*$', r'```.*?```', r'`[^`\n]*`', r'\]\([^)]*\)', r'<!--.*?-->',              # Code, link targets.
    r'\b\d{4}-\d{2}-\d{2}(T[\d:]+Z?)?\b', r'\b[0-9a-f]{7,40}\b',                           # Dates, commits.
    r'\d+(?:\.\d+)?% interval', r'\b(?:Table|Tables|Fig\.|Figure|Eq\.|issue|#)\s?\d+[a-z]?',
    r'~\s?\d+(?:[.-]\d+)*',                                                               # A rough label: ~2 min.
    r'\d+(?:\.\d+)?e-?\d+')]


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
  """The measurements a Markdown text states: decimals, ratios, integers with a unit; '4 min 5 s' in seconds.
  every: bare integers too (what a data file holds)."""
  text = _blank(text)
  found = [Token(int(m.group(1)) * SCALES[m.group(2)] + int(m.group(3)) * SCALES[m.group(4)], 0, 'time', 1., False,
                 m.group(0)) for m in COMPOSITE_TIME.finditer(text)]
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
                       signed, number))
  return found


def test_tokens_take_decimals_ranges_ratios_and_integers_with_units():
  text = ('FreeNeRF 12.5 dB against 6.3; 2.3-3.4x the floor, 0.6x the time; [0.40, 0.70] 95% interval; '
          'all 77 photos; 1656 passed in 882 s; 4 min 5 s; 1.8 min; 7% of pixels; -0.47 dB and +2.05; 3 views, '
          '2000 steps; orbax 0.12.4, commit 62ae429, 2026-11-26, scan24, `Config.x = 0.9`, [a](b_1.5.md), '
          'Table 5a, 5e-3, 11.43, 11.00 dB. The end: 6.3.')
  got = [(t.text, t.kind, t.signed) for t in tokens(text)]
  assert got == [('4 min 5 s', 'time', False), ('12.5', 'dB', False), ('6.3', None, False), ('2.3', 'ratio', False),
                 ('3.4', 'ratio', False), ('0.6', 'ratio', False), ('0.40', None, False), ('0.70', None, False),
                 ('77', None, False), ('1656', None, False), ('882', 'time', False), ('1.8', 'time', False),
                 ('7', 'percent', False), ('-0.47', 'dB', True), ('+2.05', None, True), ('11.43', 'dB', False),
                 ('11.00', 'dB', False), ('6.3', None, False)]
  assert tokens('1.8 min')[0].seconds == 60. and tokens('4 min 5 s')[0].value == 245
  assert tokens('41 h 22 min')[0].value == 41 * 3600 + 22 * 60


# ---------------------------------------------------------------------------------------------- data


class Value(NamedTuple):
  """A number of a data file and the kind its name gives it (a JSON key, a CSV column, a Markdown unit)."""
  value: float
  kind: Optional[str]


KIND_NAMES = [(re.compile(r'psnr|\bdb\b', re.I), 'dB'), (re.compile(r'second|seconds|\btime\b|_s\b|\bmin\b|\bms\b'
                                                                    r'|minutes', re.I), 'time'),
              (re.compile(r'pct|percent|within|%|coverage', re.I), 'percent'), (re.compile(r'bytes', re.I), 'bytes')]
NAME_SECONDS = [(re.compile(r'\bms\b|_ms\b', re.I), 1e-3), (re.compile(r'\bmin\b|minutes', re.I), 60.),
                (re.compile(r'\bhours?\b', re.I), 3600.)]


def _kind(name: str):
  """(kind, seconds per unit) that a value's name gives it."""
  kind = next((k for pattern, k in KIND_NAMES if pattern.search(name)), None)
  scale = next((s for pattern, s in NAME_SECONDS if pattern.search(name)), 1.) if kind == 'time' else None
  return kind, scale


def _named(value, name: str) -> List[Value]:
  kind, scale = _kind(name)
  return [Value(float(value) * (scale or 1.), kind)]


def _json_values(node, name: str = '') -> List[Value]:
  """Every number of a JSON value (numbers written as strings too), named by its key path; per_image left out."""
  if isinstance(node, dict):  # Keys name things with numbers too: 'sphere 1 (r 0.39)'.
    return [v for k, child in node.items() if k != 'per_image'
            for v in _json_values(child, f'{name}.{k}') + [_stated(t) for t in tokens(k, every=True)]]
  if isinstance(node, list):
    return [v for child in node for v in _json_values(child, name)]
  if isinstance(node, bool) or node is None:
    return []
  if isinstance(node, (int, float)):
    return _named(node, name) if math.isfinite(node) else []
  try:
    return _named(float(node), name)
  except ValueError:
    return [_stated(t) for t in tokens(node, every=True)] if len(node) < 400 else []


def _csv_values(text: str, delimiter: str) -> List[Value]:
  """The numbers of a CSV or TSV, each named by its column and its row's words (e.g. a comparison's metric)."""
  rows = list(csv.reader(io.StringIO(text), delimiter=delimiter))
  if not rows:
    return []
  found = []
  for row in rows[1:]:
    words = ' '.join(c for c in row if not _is_number(c))
    for header, cell in zip(rows[0], row):
      if _is_number(cell):
        found += _named(cell, f'{header} {words}')
  return found


def _is_number(text: str) -> bool:
  try:
    float(text)
    return True
  except ValueError:
    return False


def _stated(token: Token) -> Value:
  """A token of a data file as a value (times in seconds)."""
  return Value(token.value * (token.seconds or 1.), token.kind)


def _markdown_values(text: str) -> List[Value]:
  """The measurements a Markdown text states; in a table, each cell's column header names its kind too."""
  found = [_stated(t) for t in tokens(text, every=True)]
  header = None
  for line in text.splitlines():
    if not line.startswith('|'):
      header = None
      continue
    cells = [c.strip() for c in line.strip().strip('|').split('|')]
    if set(line) <= set('|-: '):
      continue
    if header is None:
      header = cells
      continue
    for name, cell in zip(header, cells):
      kind, scale = _kind(name)
      found += [_stated(t) if t.kind else Value(t.value * (scale or 1.), kind) for t in tokens(cell, every=True)]
  return found


@functools.lru_cache(maxsize=None)
def data_values(path: str) -> tuple:
  """The numbers of a data file under results/ (a README: the measurements it states)."""
  with open(path, errors='replace') as f:
    text = f.read()
  if path.endswith('.jsonl'):  # An export's cells: a reference to another export's line reads that line.
    return tuple(v for entry in cells_file.read(os.path.dirname(path)).values() for v in _json_values(entry.line))
  if path.endswith('.json'):
    return tuple(_json_values(json.loads(text)))
  if path.endswith(('.csv', '.tsv')):
    return tuple(_csv_values(text, '\t' if path.endswith('.tsv') else ','))
  if path.endswith(('.log', '.txt')):
    return tuple(_log_values(text))
  return tuple(_markdown_values(text))


LOOSE = re.compile(r'(?<![\w.])[+-]?\d+(?:\.\d+)?')
CLOCK = re.compile(r'(?<![\d:])(\d+):(\d\d)(?::(\d\d))?(?![\d:])')


def _log_values(text: str) -> List[Value]:
  """Every number of a log, units glued on or not (26.83step/s), its measurements with units (41 h 22 min), and its
  clock times (02:04) in seconds."""
  found = [Value(float(m.group(0)), None) for m in LOOSE.finditer(text)] + [_stated(t) for t in tokens(text)]
  for m in CLOCK.finditer(text):
    parts = [int(p) for p in m.groups() if p is not None]
    found.append(Value(float(sum(p * 60 ** (len(parts) - 1 - i) for i, p in enumerate(parts))), 'time'))
  return found


# ---------------------------------------------------------------------------------------------- backing


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


def linked_files(unit: str, document: str) -> list:
  """The files under results/ that a unit links (a folder: its README.md), as absolute paths."""
  found = []
  for link in LINK.findall(unit):
    path = os.path.normpath(os.path.join(ROOT, os.path.dirname(document), link))
    path = os.path.join(path, 'README.md') if os.path.isdir(path) else path
    if path.startswith(RESULTS + os.sep) and os.path.isfile(path) and path.endswith(DATA_SUFFIXES):
      found.append(path)
  return found


def beside(document: str) -> list:
  """The data files a results README sits among ([] for README.md and docs/)."""
  path = os.path.join(ROOT, document)
  return _data_files(os.path.dirname(path)) if path.startswith(RESULTS + os.sep) else []


MEASURED = re.compile(r'\d\s?(dB|%|x\b|ms\b|s\b|min\b|GB\b|MB\b)|PSNR|SSIM|LPIPS|FLOP|steps/s|rays/s')


def _kin(token: Token, value: Value) -> bool:
  """Whether a value may back a token: a token stated in dB, a time, a percentage or a size only by a value of that
  kind or of none."""
  return token.kind not in ('dB', 'time', 'percent', 'bytes') or value.kind in (token.kind, None)


def backed(token: Token, values) -> bool:
  """Whether a value, rounded to the digits stated, gives the token (by magnitude when no sign is written)."""
  stated = f'{token.value:.{token.digits}f}'
  for value in values:
    if not _kin(token, value):
      continue
    number = value.value if token.signed else abs(value.value)
    candidates = [number]
    if token.kind in ('time', 'bytes'):  # Seconds or bytes; a value of no kind may be in the unit stated.
      candidates = [number / (token.seconds or 1.)] + ([number] if value.kind is None else [])
    elif token.kind == 'percent':
      candidates.append(number * 100.)
    if any(f'{c:.{token.digits}f}' == stated for c in candidates):
      return True
  return False


def units(markdown: str):
  """The paragraphs, list items and table rows of a Markdown text, code blocks left out."""
  return UNIT_BREAK.split(re.sub(r'```.*?```', '', markdown, flags=re.S))


def unbacked(markdown: str, document: str) -> list:
  """[(number as written, the unit's start)] of the measurements a document states that no file backs."""
  around = [v for f in beside(document) for v in data_values(f)]
  missing = []
  for unit in units(markdown):
    linked = linked_files(unit, document)
    if not (linked or around or MEASURED.search(_blank(unit))):
      continue
    values = around + [v for f in linked for v in data_values(f)]
    missing += [(t.text, unit.strip()[:90]) for t in tokens(unit) if not backed(t, values)]
  return missing


def _read(document: str) -> str:
  with open(os.path.join(ROOT, document)) as f:
    return f.read()


@pytest.mark.parametrize('document', DOCUMENTS)
def test_every_measurement_is_in_a_file_beside_or_linked(document):
  missing = unbacked(_read(document), document)
  assert not missing, f'{document}: numbers that no file it links (or that sits beside it) backs: {missing}'


def test_a_number_is_compared_at_the_digits_stated_and_by_kind():
  values = [Value(12.4981, 'dB'), Value(0.6049, None), Value(421.3, 'time'), Value(0.071, 'percent'),
            Value(-0.47, None), Value(108.2, 'time'), Value(3.3, 'time')]
  ok = ('FreeNeRF 12.5 dB and 12.50 dB and 12.498 dB; 0.60 and 0.6x; 7 min 1 s; 7% of pixels; 0.47 dB; -0.47; '
        '1.8 min; 421 s; 3.3 s')
  assert [t.text for t in tokens(ok) if not backed(t, values)] == []
  wrong = 'FreeNeRF 12.4 dB; 12.49 dB; 0.61; 7 min 2 s; 8% of pixels; +0.47; 1.9 min; 3.3 dB; 421.3 min'
  assert [t.text for t in tokens(wrong) if not backed(t, values)] == [
      '7 min 2 s', '12.4', '12.49', '0.61', '8', '+0.47', '1.9', '3.3', '421.3']


# The substitutions that the substring match of the previous check let through (issue 53), each in the README.
SUBSTITUTIONS = [('FreeNeRF 12.5 dB', 'FreeNeRF 12.4 dB'), ("mip-NeRF's 6.3", "mip-NeRF's 6.8"),
                 ('by 0.55 dB', 'by 0.5 dB'), ('2.3-3.4x', '2.3-9.9x'), ('all 77 photos', 'all 78 photos')]


@pytest.mark.parametrize('right, wrong', SUBSTITUTIONS)
def test_a_wrong_number_in_the_readme_is_found(right, wrong):
  text = _read('README.md')
  assert right in text, f'the README no longer says {right!r}'
  assert unbacked(text, 'README.md') == []
  assert [n for n, _ in unbacked(text.replace(right, wrong), 'README.md')] == [
      re.search(NUMBER, wrong.replace('2.3-', '')).group(0)]


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
