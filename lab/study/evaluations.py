"""A study's further evaluations: each finished cell's final model evaluated again under settings that change nothing
it trained, without training it again.

  [evaluations.test_pose]
  bindings = ["Config.test_pose_steps = 100"]   # BARF's test-time pose optimization of the test cameras

Only bookkeeping settings may be bound (those left out of a run's fingerprint: runs.NOT_FINGERPRINTED), and not the
ones the runner sets (where the run and its outputs live, its name). Per cell and evaluation, in the cell's folder:
evaluations/<name>/bindings.json (the bindings, written before the evaluation runs: an evaluation whose bindings the
study file has changed since is refused, naming it) and the evaluation's outputs in
evaluations/<name>/test_preds_step_<step>/ (Config.output_dir; metrics.json as eval.py writes it). results.csv gets a
column <metric>@<name> for each of its means, which [plot] metrics and the comparisons may name; an export carries
each cell's evaluations in its line of cells.jsonl, and --reuse places them back. A reused cell has no checkpoint, so
an evaluation it lacks cannot run: it is named in a warning and its columns stay empty.
"""

import json
import os
import re
from typing import Callable, Dict, Optional, Tuple

from internal import atomic
from internal import runs

FOLDER = 'evaluations'
# In a cell's folder: {name: bindings} of the evaluations the study asks of it, written by the runner on every run
# (the cell's process reads it; a finished cell's cell_spec.json is never written again).
WANTED_FILE = 'evaluations.json'
BINDINGS_FILE = 'bindings.json'
METRICS_FILE = 'metrics.json'
# Bookkeeping settings that the runner sets for every evaluation (the run's folder, the outputs' folder, its name).
RUNNER_SETTINGS = ('checkpoint_dir', 'output_dir', 'expname')
_BINDING = re.compile(r'\s*Config\.(\w+)\s*=')


def check_bindings(bindings: Tuple[str, ...], fail: Callable[[str], None]) -> None:
  """fail(message) for the first binding that is not `Config.<bookkeeping setting> = value` the runner leaves free."""
  for binding in bindings:
    match = _BINDING.match(binding)
    name = match.group(1) if match else None
    if name in RUNNER_SETTINGS:
      fail(f'{binding!r}: Config.{name} is set by the runner for every evaluation')
    if name not in runs.NOT_FINGERPRINTED:
      fail(f'{binding!r}: expected Config.<setting> = value of a setting that changes nothing training computes '
           f'(the model is evaluated as it trained), one of {sorted(set(runs.NOT_FINGERPRINTED) - set(RUNNER_SETTINGS))}')


def folder(cell_path: str, name: str) -> str:
  """<cell>/evaluations/<name>: Config.output_dir of the evaluation."""
  return os.path.join(cell_path, FOLDER, name)


def metrics_path(cell_path: str, name: str, step: int) -> str:
  """The evaluation's metrics.json for the cell's final step."""
  return os.path.join(folder(cell_path, name), f'test_preds_step_{step}', METRICS_FILE)


def _read_json(path: str):
  try:
    with open(path) as f:
      return json.load(f)
  except (UnicodeDecodeError, json.JSONDecodeError) as e:
    raise ValueError(f'{path}: not valid JSON ({e}); expected what lab.study wrote (delete the folder of that '
                     'evaluation to run it again)') from None


def claim_bindings(cell_path: str, name: str, bindings: list) -> None:
  """Records the evaluation's bindings before it runs; ValueError naming the file when it ran with others."""
  path = os.path.join(folder(cell_path, name), BINDINGS_FILE)
  if os.path.isfile(path):
    recorded = _read_json(path)
    if recorded != list(bindings):
      raise ValueError(f'{path}: the evaluation {name!r} ran with {recorded}, the study file now gives {list(bindings)}; '
                       'expected the same (delete that folder to evaluate again, or give the new one another name)')
    return
  os.makedirs(os.path.dirname(path), exist_ok=True)
  atomic.write_text(path, json.dumps(list(bindings)))


def write_wanted(cell_path: str, wanted: Dict[str, tuple]) -> None:
  """Records {name: bindings} of the evaluations the study asks of the cell (nothing for a study without any, whose
  cells never had them)."""
  path = os.path.join(cell_path, WANTED_FILE)
  if wanted or os.path.isfile(path):
    atomic.write_text(path, json.dumps({name: list(b) for name, b in wanted.items()}))


def missing(cell_path: str, step: int) -> Dict[str, list]:
  """{name: bindings} of the evaluations the study asks of the cell that its final step lacks."""
  path = os.path.join(cell_path, WANTED_FILE)
  wanted = _read_json(path) if os.path.isfile(path) else {}
  return {name: b for name, b in wanted.items() if not os.path.isfile(metrics_path(cell_path, name, step))}


def run_missing(cell_path: str, step: int, cell_config) -> None:
  """Evaluates the cell's run for each evaluation the study asks of it that it lacks; cell_config(extra bindings)
  is the context manager of the cell's Config with those bindings last. ValueError naming the evaluation when its
  Config would train another model than the run's (a bookkeeping setting that resolves into a trained one)."""
  for name, bindings in missing(cell_path, step).items():
    extra = list(bindings) + [f'Config.output_dir = {folder(cell_path, name)!r}']
    with cell_config(extra) as config:
      stored = runs.read_fingerprint(config.checkpoint_dir)
      changed = stored and runs.differences({**stored, 'Config.precision': config.precision}, config)
      if changed:
        raise ValueError(f'{cell_path}: evaluation {name!r}: its bindings change what the run trained ({changed}); '
                         'expected settings that only change how the trained model is evaluated')
      claim_bindings(cell_path, name, bindings)
      print(f'evaluation {name}: {" ".join(bindings)}')
      runs.evaluate(config)


def recorded(cell_path: str, step: int, names) -> Dict[str, dict]:
  """{name: {'bindings', 'evaluation': metrics.json}} of the named evaluations the cell's final step has."""
  found = {}
  for name in names:
    path = metrics_path(cell_path, name, step)
    if os.path.isfile(path):
      found[name] = {'bindings': _read_json(os.path.join(folder(cell_path, name), BINDINGS_FILE)),
                     'evaluation': _read_json(path)}
  return found


def columns(cell_path: str, step: int, names) -> Dict[str, Optional[float]]:
  """{'<metric>@<name>': mean} of the named evaluations the cell's final step has."""
  found = recorded(cell_path, step, names)
  return {f'{metric}@{name}': value for name in found for metric, value in found[name]['evaluation']['means'].items()}


def place(cell_path: str, step: int, exported: Dict[str, dict]) -> None:
  """Writes an export's evaluations of a cell ({name: {'bindings', 'evaluation'}}) where a run here writes them."""
  for name, entry in exported.items():
    path = metrics_path(cell_path, name, step)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    atomic.write_text(os.path.join(folder(cell_path, name), BINDINGS_FILE), json.dumps(entry['bindings']))
    atomic.write_text(path, json.dumps(entry['evaluation'], indent=1))
