"""What is committed under results/ names no folder of the machine that wrote it (issue 59): the writers record
paths relative to the repository (a command's words, a study export's run folders as {out}/<study>/<cell>/run)."""

import json
import os
import re

import pytest

from internal import cli
from tools import provenance
from tools.study import export

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RESULTS = os.path.join(ROOT, 'results')
# An absolute path into a developer's machine: its checkouts and data (/work), home (/root) or scratch (/tmp).
MACHINE_PATH = re.compile(r'(?<![\w.~/-])/(?:work|root|tmp|home)/[\w.@+,=-]+')
BINARY = ('.png', '.jpg', '.npz', '.npy', '.gz', '.pkl')
# Left as written: logs are what a program printed (pytest's and Python's warnings name the files that ran), and
# results/gpu/ holds what lent GPU machines wrote (their own /tmp and /root), copied as they wrote it.
VERBATIM = ('.log',)
LENT_MACHINES = os.path.join(RESULTS, 'gpu') + os.sep


def _committed_texts() -> list:
  """The text files under results/ that this machine's tools wrote, relative to the repository."""
  found = []
  for folder, _, names in os.walk(RESULTS):
    for name in names:
      path = os.path.join(folder, name)
      if name.endswith(BINARY + VERBATIM) or (path.startswith(LENT_MACHINES) and name != 'README.md'):
        continue
      found.append(os.path.relpath(path, ROOT))
  return sorted(found)


@pytest.mark.parametrize('name', _committed_texts())
def test_no_committed_result_names_a_folder_of_the_machine_that_wrote_it(name):
  with open(os.path.join(ROOT, name), errors='replace') as f:
    found = [f'line {n}: {m.group(0)}' for n, line in enumerate(f, 1) for m in MACHINE_PATH.finditer(line)]
  assert not found, (f'{name} names absolute paths of the machine that wrote it: {found[:5]}; expected paths '
                     'relative to the repository (../shared/data, out/studies, results/...)')


def test_a_recorded_command_names_paths_relative_to_the_repository():
  outside = os.path.join(os.path.dirname(cli.REPOSITORY), 'elsewhere', 'out')
  words = ['python', '-m', 'tools.study', 'x.toml', '--export', os.path.join(cli.REPOSITORY, 'out', 'x'),
           f'--out={outside}', f"Config.data_dir = '{outside}/a'", '--shard', '0/2']
  assert cli.recorded_command(words) == ("python -m tools.study x.toml --export out/x --out=../elsewhere/out "
                                         "\"Config.data_dir = '../elsewhere/out/a'\" --shard 0/2")
  assert provenance.record(words)['command'] == cli.recorded_command(words)
  assert cli.command_line('tools.study', words[3:]) == cli.recorded_command(words)


def test_an_export_names_a_cells_run_folder_by_its_template(tmp_path):
  cell = tmp_path / 'out' / 'study' / 'm__s__seed=0'
  evaluation = {'means': {'psnr': 10.}, 'run_dir': str(cell / 'run')}
  assert export._portable(evaluation, str(cell)) == {  # pylint: disable=protected-access
      'means': {'psnr': 10.}, 'run_dir': '{out}/study/m__s__seed=0/run'}
  reused = {'means': {'psnr': 10.}, 'run_dir': '{out}/other/m__s__seed=0/run'}  # Placed by --reuse: kept.
  assert export._portable(reused, str(cell)) == reused  # pylint: disable=protected-access


def test_the_committed_exports_name_their_run_folders_by_template():
  for folder, _, names in os.walk(RESULTS):
    if 'cells.jsonl' in names:
      with open(os.path.join(folder, 'cells.jsonl')) as f:
        for line in map(json.loads, f):
          run_dir = (line.get('evaluation') or {}).get('run_dir', '{out}/')
          assert run_dir.startswith('{out}/'), f'{folder}/cells.jsonl: cell {line["cell"]} names {run_dir}'
