"""The pictures committed under results/ are ones a reader opens, at sizes a repository carries (issue 59): each is
named by a README or a doc (a link, or its name in the text: `psnr_vs_step.png`, `side_by_side_<scene>.png`,
`lpips*_vs_T.png`, or a folder of them: `test_truth/`), and none is larger than MAX_BYTES."""

import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, 'results')
MAX_BYTES = 1_000_000
# A picture's name or a folder in a document: a link target or a word, with <placeholders> and * as wildcards.
NAMED = re.compile(r"[\w./<>*=@-]*\.png\b|[\w./<>*=@-]+/(?=[`)\s,;])")


def _documents() -> list:
  """The Markdown files that name pictures: README.md, docs/*.md and every README.md under results/."""
  found = [os.path.join(ROOT, 'README.md')]
  found += [os.path.join(ROOT, 'docs', n) for n in sorted(os.listdir(os.path.join(ROOT, 'docs'))) if n.endswith('.md')]
  return found + [os.path.join(folder, 'README.md') for folder, _, names in os.walk(RESULTS) if 'README.md' in names]


def _pattern(document: str, name: str):
  """The regular expression of the files a name in a document names: relative to the document's folder (a bare name
  also in its subfolders, which its README speaks for); a folder names what it holds."""
  folder = os.path.dirname(document)
  path = os.path.normpath(os.path.join(folder, name))
  wild = re.escape(path).replace(r'\*', '[^/]*')
  wild = re.sub(r'\\<[^>]*\\>|<[^>]*>', '[^/]*', wild)
  if name.endswith('/'):
    return re.compile(wild + '/.*')
  if '/' not in name:
    return re.compile(re.escape(folder) + '/(?:.*/)?' + wild[len(re.escape(folder)) + 1:])
  return re.compile(wild)


def _patterns() -> list:
  found = []
  for document in _documents():
    with open(document, errors='replace') as f:
      found += [_pattern(document, name) for name in NAMED.findall(f.read())]
  return found


def pictures() -> list:
  """The PNG files under results/, absolute."""
  return sorted(os.path.join(folder, n) for folder, _, names in os.walk(RESULTS) for n in names if n.endswith('.png'))


def test_every_committed_picture_is_named_by_a_readme_or_doc():
  patterns = _patterns()
  unnamed = [os.path.relpath(p, ROOT) for p in pictures() if not any(r.fullmatch(p) for r in patterns)]
  assert not unnamed, (f'{len(unnamed)} pictures under results/ that no README or doc names (link them, name them '
                       f'in the text, or delete them): {unnamed[:10]}')


@pytest.mark.parametrize('path', pictures(), ids=lambda p: os.path.relpath(p, ROOT))
def test_every_committed_picture_is_small(path):
  size = os.path.getsize(path)
  assert size <= MAX_BYTES, (f'{os.path.relpath(path, ROOT)} is {size:,} bytes; expected at most {MAX_BYTES:,} '
                             '(internal/evaluation/vis.py save_picture writes a palette PNG)')
