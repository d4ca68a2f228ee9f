"""The looks of a study: the seed counts at which its comparisons were read, recorded in <study folder>/looks.json.

A study whose comparisons were read at 3 seeds and again at 5 (seeds added because every interval held 0) had two
chances to declare a difference by chance; its intervals are corrected for both (tools/study/stats.py, look_level).
The study file may say so (`looks = [3, 5]`); the runner also records a look itself each time it writes the
comparisons of a finished study (every cell of the study file as it then was), so that seeds added in the same
study folder count without anyone declaring them. An export copies the record, and --reuse of an export of the same
study takes its looks along.
"""

import dataclasses
import json
import os
from typing import List

from internal import atomic
from tools.study import cells_file
from tools.study import spec as study_spec
from tools.study import stats as study_stats

FILE = 'looks.json'  # {"seed_counts": [3, 5]}: the counts at which the study's comparisons were written.


def recorded(folder: str) -> List[int]:
  """The seed counts folder's looks.json records ([] without one); ValueError naming a file that holds no counts."""
  path = os.path.join(folder, FILE)
  if not os.path.isfile(path):
    return []
  counts = cells_file.read_json(path).get('seed_counts')
  if not isinstance(counts, list) or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1
                                             for n in counts):
    raise ValueError(f'{path}: {counts!r}; expected {{"seed_counts": [n, ...]}}, the seed counts at which the '
                     'comparisons were written (tools/study/looks.py)')
  return counts


def record(folder: str, counts) -> None:
  """Adds counts to folder's looks.json (written only when that changes it)."""
  known = recorded(folder)
  merged = sorted(set(known) | set(counts))
  if merged != sorted(known):
    atomic.write_text(os.path.join(folder, FILE), json.dumps({'seed_counts': merged}) + '\n')


def with_recorded(study: study_spec.Study, folder: str) -> study_spec.Study:
  """The study with the looks folder records added to its own (those up to its seed count: a look at more seeds
  than it has now is not one of this study's reads)."""
  count = study_stats.seed_count(study)
  if count is None:
    return study
  found = {n for n in recorded(folder) if n <= count}
  return dataclasses.replace(study, looks=tuple(sorted(set(study.looks) | found | {count})))


def record_if_finished(study: study_spec.Study, folder: str, rows: List[dict]) -> None:
  """Records a look at the study's seed count, with those its file declares (so that an export carries them), when
  it has seeds, comparisons and every cell finished (rows: results.csv's)."""
  count = study_stats.seed_count(study)
  if count is not None and study.compare and rows and all(r.get('status') == 'done' for r in rows):
    record(folder, [*study.looks, count])


def describe(study: study_spec.Study) -> str:
  """One line for comparisons.md: the intervals' level and the looks it is corrected for."""
  counts, level = study_stats.looks(study), study_stats.level_text(study_stats.look_level(study))
  if not counts:
    return f'Paired {level} intervals (Student\'s t over the pairs).'
  if len(counts) == 1:
    return (f'Paired {level} intervals (Student\'s t over the pairs), one look: read at {counts[0]} seeds only (the '
            f'seed count fixed in advance; neither the study file\'s `looks` nor {FILE} names another).')
  read_at = ', '.join(map(str, counts[:-1])) + f' and {counts[-1]}'
  return (f'Paired {level} intervals (Student\'s t over the pairs), corrected for {len(counts)} looks: read at '
          f'{read_at} seeds (the study file\'s `looks` and {FILE}), each interval at 1 - 5% / {len(counts)} '
          '(Bonferroni), so that all looks together declare a difference where there is none at most 5% of the time.')
