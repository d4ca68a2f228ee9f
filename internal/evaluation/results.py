"""The metrics.json record of an evaluated run: its schema, the protocol's scene names, reading and writing."""

import json
import math
import pathlib
from typing import List, Optional, Sequence

from internal import atomic
from internal.datasets import loader
from internal.evaluation import metric_registry

METRICS_FILENAME = 'metrics.json'
# metrics.json (written by internal/evaluation/evaluate.py through `make_record` / `write_record`):
#   {"dataset": one of DATASETS, "scene": str (e.g. "scan8", "fern", "lego"), "n_input_views": int,
#    "method": str (e.g. "freenerf", "mipnerf"), "step": int,
#    "means": {metric: float or null}, the mean over test views of each per-image value (null: not available),
#    "per_image": [{"id": int, metric: float or null, ...}], one entry per evaluated test view, in test order,
#    "complete": bool, true when every test view was evaluated at full resolution,
#    optional "seeds": [Config.jax_rng_seed, Config.np_rng_seed]: runs that differ only here are replicates}
# Metric names are those of internal/evaluation/metric_registry.py.
RECORD_FIELDS = {'dataset': str, 'scene': str, 'n_input_views': int, 'method': str, 'step': int,
                 'means': dict, 'per_image': list, 'complete': bool}
DATASETS = loader.RESULT_DATASETS
# The protocol's test scenes of each dataset, over which the tables average.
EXPECTED_SCENES = {name: loader.REGISTRY[name].protocol_scenes for name in DATASETS}


def mean(values: Sequence[Optional[float]]) -> Optional[float]:
  """Mean of the values; None when there are none or one is None."""
  if not values or any(v is None for v in values):
    return None
  return float(math.fsum(values) / len(values))


def check_record(record: dict, where: str) -> None:
  """Raises ValueError naming `where` and the field when a record does not follow the schema."""
  if not isinstance(record, dict):
    raise ValueError(f'{where}: a JSON {type(record).__name__}; expected the object eval.py writes')
  for field, kind in RECORD_FIELDS.items():
    if not isinstance(record.get(field), kind) or (kind is int and isinstance(record[field], bool)):
      raise ValueError(f'{where}: field {field!r} = {record.get(field)!r}; expected {kind.__name__}')
  if record['dataset'] not in DATASETS:
    raise ValueError(f'{where}: dataset {record["dataset"]!r}; expected one of {list(DATASETS)}')
  unknown = sorted(set(record['means']) - set(metric_registry.METRICS))
  if unknown:
    raise ValueError(f'{where}: metrics {unknown} are not in internal/evaluation/metric_registry.py; expected '
                     f'some of {list(metric_registry.METRICS)}')


def make_record(dataset: str, scene: str, n_input_views: int, method: str, step: int,
                per_image: List[dict], complete: bool) -> dict:
  """A metrics.json record; means[m] = mean of per_image[i][m] (None if any image lacks m)."""
  names = [name for name in (per_image[0] if per_image else {}) if name != 'id']
  record = {'dataset': dataset, 'scene': scene, 'n_input_views': n_input_views, 'method': method,
            'step': step, 'means': {name: mean([img.get(name) for img in per_image]) for name in names},
            'per_image': per_image, 'complete': complete}
  check_record(record, f'record {dataset}/{scene}')
  return record


def write_record(path, record: dict) -> None:
  """Writes a record as JSON (after checking it)."""
  check_record(record, str(path))
  atomic.write_text(path, json.dumps(record, indent=1))


def read_record(path) -> dict:
  """Reads and checks a metrics.json file; ValueError naming it when it cannot be read or parsed."""
  try:
    record = json.loads(pathlib.Path(path).read_text())
  except (OSError, ValueError) as err:  # ValueError: bad JSON or bytes that are not UTF-8.
    raise ValueError(f'{str(path)!r} cannot be read as JSON ({err}); expected the metrics.json written by '
                     'eval.py') from err
  if isinstance(record, dict) and record.get('dataset') in loader.RENAMED:  # Evaluated before a loader's rename.
    record['dataset'] = loader.RENAMED[record['dataset']]
  check_record(record, str(path))
  return record
