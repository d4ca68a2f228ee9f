"""Each number the README and docs/ state beside a link to a result file is in that file: one home per number.

A unit is a paragraph, a list item or a table row. Where it links to files under results/ (a folder's README.md
for a folder), every decimal number it states must appear in one of them, so that a figure quoted in the front
door cannot drift from the file the command that measured it wrote.
"""

import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCUMENTS = ['README.md'] + sorted(os.path.join('docs', n) for n in os.listdir(os.path.join(ROOT, 'docs'))
                                   if n.endswith('.md'))
LINK = re.compile(r'\]\(([^)#\s]+)(?:#[^)]*)?\)')
DECIMAL = re.compile(r'(?<![\w.\-/])(\d+\.\d+)(?![\w.])')
UNIT_BREAK = re.compile(r'\n\s*\n|\n(?=\s*- )|\n(?=\| )')


def units(markdown: str):
  """The paragraphs, list items and table rows of a Markdown text, code blocks left out."""
  return UNIT_BREAK.split(re.sub(r'```.*?```', '', markdown, flags=re.S))


def result_files(unit: str, document: str):
  """The files under results/ that a unit links to (a folder's README.md for a folder), as absolute paths."""
  found = []
  for link in LINK.findall(unit):
    path = os.path.normpath(os.path.join(ROOT, os.path.dirname(document), link))
    path = os.path.join(path, 'README.md') if os.path.isdir(path) else path
    if path.startswith(os.path.join(ROOT, 'results') + os.sep) and os.path.isfile(path):
      found.append(path)
  return found


def unhoused_numbers(markdown: str, document: str):
  """[(number, unit)] of decimal numbers stated beside result links but in none of the linked files."""
  missing = []
  for unit in units(markdown):
    files = result_files(unit, document)
    if files:
      text = ' '.join(open(f, errors='replace').read() for f in files)
      missing += [(n, unit.strip()[:100]) for n in DECIMAL.findall(unit) if n not in text]
  return missing


def test_a_number_absent_from_its_linked_file_is_found(tmp_path):
  text = 'FreeNeRF leads by 0.55 dB and 9.99 dB ([fern](results/studies/seeds_llff_quick/README.md)).'
  assert [n for n, _ in unhoused_numbers(text, 'README.md')] == ['9.99']
  assert unhoused_numbers('0.55 and 9.99 with no link to a result', 'README.md') == []


@pytest.mark.parametrize('document', DOCUMENTS)
def test_every_number_beside_a_result_link_is_in_the_linked_file(document):
  with open(os.path.join(ROOT, document)) as f:
    missing = unhoused_numbers(f.read(), document)
  assert not missing, f'{document}: numbers not in the result files they link to: {missing}'
