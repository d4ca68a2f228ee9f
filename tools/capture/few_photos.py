"""Structure-from-motion on a few photos alone: how often 3, 6 and 9 photos register, and how far their cameras are
from those of a model of all the photos.

Usage: python -m tools.capture.few_photos CAPTURE_DIR --out RESULTS.json [--sizes 3 6 9] [--subsets 8] [--seed 0]
                                          [--max_size 800] [--work out/capture/few_photos]
       python -m tools.capture.few_photos --summarize --out RESULTS.json

CAPTURE_DIR is a capture of every photo (its images/ and the all-photo model sparse/0, e.g. the cup's). For each
size n, seeded subsets of its photos of four kinds (KINDS): 'spread', n photos evenly spread along the whole arc
(the capture loader's order of the model's cameras), each moved at random by up to a quarter of their spacing;
'half' and 'quarter', the same over that part of the arc from a random start; 'random', n photos drawn at random
(anywhere). Each subset is run through `python -m tools.capture CAPTURE_DIR/images --photos NAMES --out
<work>/<kind>_<n>_<k>` in this process: structure-from-motion on those photos alone. A subset registers whole when
every photo is in the capture's model; the registered cameras of every capture made are compared with the all-photo
model's after a similarity fit (poses.pose_errors: rotation in degrees, centre distance as a fraction of the
all-photo capture's camera distance), and a capture whose median rotation error is over OFF_DEGREES is counted off.
Writes the JSON (provenance, every run) and its Markdown summary beside it (same name, .md): per size and kind, and
per size the distribution of the captures' median rotation errors (median, quartiles, largest, how many are off),
since a few wrong captures hide behind a median. --summarize writes the Markdown again from an existing JSON's runs
(no structure-from-motion).
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import contextlib
import io
import json
import os
import sys
import time

import gin
import numpy as np

from internal import atomic
from internal import cli
from internal import config_loader
from internal.cameras import alignment
from internal.datasets import colmap_model
from internal.datasets import capture as capture_loader
from tools import provenance
from tools.capture import CaptureError, pipeline, poses, sfm

KINDS = {'spread': 1., 'half': .5, 'quarter': .25, 'random': None}  # The fraction of the arc a subset spans.
JITTER = .25  # Spread subsets: each photo moved by up to this fraction of the spacing.
ERRORS = ('median_rotation_deg', 'max_rotation_deg', 'median_position', 'max_position')
OFF_DEGREES = 5.  # A capture whose cameras are this far off at the median has wrong cameras, not noisy ones.


def arc_names(capture_dir: str) -> list:
  """The capture's registered images in the loader's order along the arc."""
  gin.clear_config()
  config = config_loader.load_config([os.path.join(pipeline.REPO, pipeline.CONFIG)],
                                     [f'Config.data_dir = {capture_dir!r}'])
  found = capture_loader.read_capture(config)
  return [found.names[i] for i in capture_loader.arc_order(found)]


def subset(order: list, n: int, span, rng: np.random.Generator) -> list:
  """n names of order (along the arc): spread evenly over the fraction span of it, jittered, or at random (None)."""
  last = len(order) - 1
  if span is None:
    return [order[i] for i in sorted(rng.choice(len(order), n, replace=False))]
  length = span * last
  start = rng.uniform(0., last - length)
  spacing = length / (n - 1)
  if spacing < 1.:
    raise ValueError(f'{n} photos do not fit apart in {span:.0%} of an arc of {len(order)} photos')
  jitter = min(JITTER, (1. - 1. / spacing) / 2.)  # Neighbours stay at least a photo apart, so n are drawn.
  places = start + np.linspace(0., length, n) + rng.uniform(-jitter, jitter, n) * spacing
  return [order[i] for i in np.clip(np.round(places), 0, last).astype(int)]


def largest_model(out: str):
  """The capture's sparse/0, else the largest model structure-from-motion left (None without one)."""
  for folder in (os.path.join(out, 'sparse', '0'), os.path.join(out, 'sfm', 'models', '0')):
    if os.path.isdir(folder):
      return colmap_model.read_model(folder)
  return None


def camera_errors(model, reference, distance: float) -> dict:
  """Median and largest rotation (degrees) and position (fraction of distance) errors of a model's cameras
  against the reference model's cameras of the same photos."""
  names, c2w = poses.model_cameras(model)
  reference_names, reference_c2w = poses.model_cameras(reference)
  found = poses.pose_errors(c2w, reference_c2w[[reference_names.index(n) for n in names]], distance)
  return {key: float((np.median if key.startswith('median') else np.max)(found[key.split('_', 1)[1]]))
          for key in ERRORS}


def run(photo_dir: str, names: list, out: str, max_size: int, reference, distance: float) -> dict:
  """One capture of the photos named: its outcome, registered photos and camera errors."""
  start, error = time.perf_counter(), None
  try:
    with contextlib.redirect_stdout(io.StringIO()):
      pipeline.make(pipeline.Options(photo_dir, out, photos=names, max_size=max_size, overwrite=True),
                    cli.command_line('tools.capture.few_photos'))
  except CaptureError as err:
    error = cli.one_line(err).split(' (what it wrote stays')[0]
  model = largest_model(out)
  registered = sorted(i.name for i in model.images.values()) if model else []
  database = os.path.join(out, 'sfm', 'database.db')
  rig = None
  if error is None:
    with open(os.path.join(out, 'report.json'), encoding='utf-8') as f:
      rig = json.load(f)['rig']
  row = {'photos': names, 'capture_made': error is None, 'error': error, 'registered': len(registered), 'rig': rig,
         'best_pair_matches': sfm.best_pair(database) if os.path.isfile(database) else None,
         'all_registered': error is None and len(registered) == len(names),
         'unregistered': [n for n in names if n not in registered], 'seconds': time.perf_counter() - start}
  if len(registered) >= pipeline.MIN_REGISTERED:
    row.update(camera_errors(model, reference, distance))
  return row


def summary_rows(runs: list) -> list:
  """Per size and kind: subsets, those registered whole, captures made (at least MIN_REGISTERED photos) and the
  photos in them, the best pairs' verified matches, and the camera errors of the captures made."""
  rows = []
  for n, kind in dict.fromkeys((r['n'], r['kind']) for r in runs):
    group = [r for r in runs if (r['n'], r['kind']) == (n, kind)]
    made = [r for r in group if r['capture_made']]
    errors = {key: [r[key] for r in made] for key in ERRORS}
    pairs = [r['best_pair_matches'] for r in group if r['best_pair_matches'] is not None]
    rows.append({'n': n, 'kind': kind, 'subsets': len(group), 'all_registered': sum(r['all_registered'] for r in group),
                 'captures_made': len(made), 'registered_in_captures_median': _median([r['registered'] for r in made]),
                 'inward': sum(r['rig'] == 'inward' for r in made),
                 'off': sum(r['median_rotation_deg'] > OFF_DEGREES for r in made),
                 'no_initial_pair': sum('no initial pair' in (r['error'] or '') for r in group),
                 'best_pair_matches_median': _median(pairs),
                 **{f'{key}_median_over_captures': _median(v) for key, v in errors.items()},
                 'worst_rotation_deg': max(errors['max_rotation_deg'], default=None),
                 'worst_position': max(errors['max_position'], default=None)})
  return rows


def distribution_rows(runs: list) -> list:
  """Per size, over the captures made of every kind: their count and the distribution of their median rotation
  errors (median, quartiles, largest, how many are over OFF_DEGREES)."""
  rows = []
  for n in dict.fromkeys(r['n'] for r in runs):
    values = np.array([r['median_rotation_deg'] for r in runs if r['n'] == n and 'median_rotation_deg' in r])
    quartiles = [float(q) for q in np.percentile(values, [25, 50, 75])] if len(values) else [None] * 3
    rows.append({'n': n, 'captures': len(values), 'q1': quartiles[0], 'median': quartiles[1], 'q3': quartiles[2],
                 'max': float(values.max()) if len(values) else None, 'off': int((values > OFF_DEGREES).sum())})
  return rows


def _median(values: list):
  """The median of values, None for none."""
  return float(np.median(values)) if values else None


def _value(value, digits: int, scale: float = 1., unit: str = '') -> str:
  """A number for the tables ('-' for none)."""
  return '-' if value is None else f'{scale * value:.{digits}f}{unit}'


def _summary_table(rows: list) -> str:
  """The Markdown table of summary_rows."""
  table = ('| photos | registered whole | captures made (photos in them, median; inward) | off | no initial pair | '
           "best pair's verified matches, median | rotation error, median (worst) | position error, median (worst) "
           '|\n|---|---|---|---|---|---|---|---|\n')
  for r in rows:
    table += (f'| {r["n"]}, {r["kind"]} | {r["all_registered"]} of {r["subsets"]} | {r["captures_made"]} '
              f'({_value(r["registered_in_captures_median"], 1)}; {r["inward"]}) | {r["off"]} | '
              f'{r["no_initial_pair"]} | '
              f'{_value(r["best_pair_matches_median"], 0)} | '
              f'{_value(r["median_rotation_deg_median_over_captures"], 2, unit=" deg")} '
              f'({_value(r["worst_rotation_deg"], 2, unit=" deg")}) | '
              f'{_value(r["median_position_median_over_captures"], 1, 100., " %")} '
              f'({_value(r["worst_position"], 1, 100., " %")}) |\n')
  return table


def _distribution_table(rows: list) -> str:
  """The Markdown table of distribution_rows."""
  table = ('| photos | captures made | median rotation error of a capture: median | quartiles | largest | '
           f'over {OFF_DEGREES:.0f} degrees |\n|---|---|---|---|---|---|\n')
  for r in rows:
    quartiles = '-' if r['q1'] is None else f'{_value(r["q1"], 2)} to {_value(r["q3"], 2, unit=" deg")}'
    table += (f'| {r["n"]} | {r["captures"]} | {_value(r["median"], 2, unit=" deg")} | {quartiles} | '
              f'{_value(r["max"], 2, unit=" deg")} | {r["off"]} of {r["captures"]} |\n')
  return table


def _runs_table(runs: list) -> str:
  """The Markdown table of every run."""
  table = ("| run | photos | registered | best pair's matches | median rotation / position error | rig | outcome |\n"
           '|---|---|---|---|---|---|---|\n')
  for r in runs:
    table += (f'| {r["label"]} | {" ".join(r["photos"])} | {r["registered"]} of {len(r["photos"])} | '
              f'{_value(r["best_pair_matches"], 0)} | {_value(r.get("median_rotation_deg"), 2, unit=" deg")} / '
              f'{_value(r.get("median_position"), 1, 100., " %")} | {r["rig"] or "-"} | '
              f'{(r["error"] or "capture made")[:160]} |\n')
  return table


def markdown(record: dict) -> str:
  """The results as Markdown: provenance, the summary table, every run."""
  return (f'# Structure-from-motion on a few of the {record["photos_in_capture"]} photos of `{record["capture"]}` '
          f'alone\n\n`{record["command"]}` at commit {record["commit"][:12]} on {record["machine"]["cpu"]} '
          f'({record["machine"]["cpu_count"]} CPUs, shared), pycolmap {record["pycolmap"]}, {record["date"]}.\n\n'
          'Registered whole: every photo of the subset in the model. A capture is made from '
          f'{pipeline.MIN_REGISTERED} registered photos up; inward: how many of them train as an inward rig (the '
          "others as forward-facing, the loader's choice from their viewing directions). Errors of the captures' "
          "registered cameras against the all-photo model's, after a similarity fit: the median over the captures "
          "of each one's median (and the worst single camera); positions as a percentage of the all-photo "
          f"capture's camera distance; off: captures whose median rotation error is over {OFF_DEGREES:.0f} "
          'degrees (wrong cameras that registered).\n\n'
          f'{_summary_table(record["summary"])}\n## The captures made, by size\n\nEvery kind together: the '
          "distribution of the captures' median rotation errors (each capture's median over its cameras), "
          f'from the runs below.\n\n{_distribution_table(distribution_rows(record["runs"]))}\n'
          f'## Every run\n\n{_runs_table(record["runs"])}')


def summarize(path: str) -> int:
  """Writes the Markdown beside the results file path again from its runs; prints the distribution."""
  if not os.path.isfile(path):
    raise FileNotFoundError(f'--out {path!r} does not exist; --summarize reads the results file a run wrote')
  with open(path, encoding='utf-8') as f:
    record = json.load(f)
  atomic.write_text(os.path.splitext(path)[0] + '.md', markdown(record))
  print(_distribution_table(distribution_rows(record['runs'])))
  return 0


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('capture_dir', nargs='?', help='a capture of every photo: images/ and its model sparse/0')
  parser.add_argument('--out', required=True, help='the results file to write (.json; a .md beside it)')
  parser.add_argument('--summarize', action='store_true',
                      help='write the .md beside --out again from its runs (no structure-from-motion)')
  parser.add_argument('--sizes', nargs='+', type=int, default=[3, 6, 9])
  parser.add_argument('--subsets', type=int, default=8, help='subsets of each kind and size')
  parser.add_argument('--seed', type=int, default=0)
  parser.add_argument('--max_size', type=int, default=pipeline.MAX_SIZE)
  parser.add_argument('--work', default=os.path.join('out', 'capture', 'few_photos'), help='where the captures go')
  args = parser.parse_args(argv)
  if args.summarize:
    return summarize(args.out)
  if args.capture_dir is None:
    parser.error('CAPTURE_DIR is required (a capture of every photo), unless --summarize')
  # The code as the runs start (a run takes minutes, in which the worktree may change).
  origin = provenance.record(['python', '-m', 'tools.capture.few_photos']
                             + list(sys.argv[1:] if argv is None else argv))
  order = arc_names(args.capture_dir)
  reference = colmap_model.read_model(os.path.join(args.capture_dir, 'sparse', '0'))
  distance = alignment.camera_distance(poses.model_cameras(reference)[1])
  runs = []
  for n in args.sizes:
    for kind_index, (kind, span) in enumerate(KINDS.items()):
      rng = np.random.default_rng([args.seed, n, kind_index])
      for k in range(args.subsets):
        label = f'{kind}_{n}_{k}'
        row = run(os.path.join(args.capture_dir, 'images'), subset(order, n, span, rng),
                  os.path.join(args.work, label), args.max_size, reference, distance)
        runs.append({'label': label, 'n': n, 'kind': kind, **row})
        print(f'{label}: {row["registered"]} of {len(row["photos"])} registered'
              + (f', median rotation error {row["median_rotation_deg"]:.2f} deg' if 'median_rotation_deg' in row
                 else '') + (f' ({row["error"][:100]})' if row['error'] else ''), flush=True)
  record = {**origin, 'capture': args.capture_dir, 'photos_in_capture': len(order), 'camera_distance': distance,
            'pycolmap': sfm.require_pycolmap().__version__, 'settings': vars(args),
            'summary': summary_rows(runs), 'runs': runs}
  os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
  atomic.write_text(args.out, json.dumps(record, indent=1))
  atomic.write_text(os.path.splitext(args.out)[0] + '.md', markdown(record))
  print(_summary_table(record['summary']))
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
