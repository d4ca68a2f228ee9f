"""Every Config field says what it does: a comment on its line or on the line above."""

import dataclasses
import pathlib
import re

from internal.configs import Config

SOURCE = pathlib.Path(__file__).resolve().parents[1] / 'internal' / 'configs.py'


def uncommented_fields(lines) -> list:
  """Names of `  name: type = value` lines with no `#` comment on them or on the line before."""
  missing = []
  for i, line in enumerate(lines):
    match = re.match(r'  (\w+): [^=]+=', line)
    if match and '#' not in line and not lines[i - 1].strip().startswith('#'):
      missing.append(match.group(1))
  return missing


def test_uncommented_fields_finds_a_bare_field():
  assert uncommented_fields(['  # Data.', '  a: int = 1  # A.', '  b: int = 2', '  # C.', '  c: int = 3']) == ['b']


def test_every_config_field_is_commented():
  lines = SOURCE.read_text().splitlines()
  declared = [m.group(1) for m in (re.match(r'  (\w+): [^=]+=', line) for line in lines) if m]
  assert declared == [f.name for f in dataclasses.fields(Config)]  # The parser sees every field.
  assert uncommented_fields(lines) == []
