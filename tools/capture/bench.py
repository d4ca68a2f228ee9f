"""Benchmark of tools.capture on photos with independent cameras: registrations, pose errors, seconds per photo.

Usage: python -m tools.capture.bench PHOTOS_DIR --reference POSES_BOUNDS.npy|CAMERAS_SPHERE.npz --out RESULTS.json
                                     [--work out/capture] [--matching sequential exhaustive] [--max_size 800]

For each matching mode, runs `python -m tools.capture PHOTOS_DIR --out <work>/<scene>_<matching>` in this process
(scene: the reference's folder name), then compares the recovered cameras with the reference (LLFF's
poses_bounds.npy, its rows in the photos' sorted name order, or DTU's calibration as an IDR cameras_sphere.npz)
after a similarity alignment (tools/capture/poses.py).
Writes the JSON (the command, commit, machine, the load average before and after each run, and per run the
registrations, the errors, the images flagged for few points, wall and CPU seconds and the seconds per photo of
extraction, matching and mapping) and the same as Markdown beside it (same name, .md).
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import json
import os
import resource
import sys

import numpy as np

from internal import atomic
from internal import cli
from internal.cameras import algebra
from internal.datasets import colmap_model, dtu
from tools import provenance
from tools.capture import CaptureError, photos, pipeline, poses, sfm

# The targets for the cup's 77 photos.
TARGETS = {'median_rotation_deg': 2., 'median_position': .05, 'total_seconds': 120.}


def cpu_seconds() -> float:
  """User + system CPU seconds of this process so far (pycolmap's threads included)."""
  usage = resource.getrusage(resource.RUSAGE_SELF)
  return usage.ru_utime + usage.ru_stime


def reference_cameras(reference: str, names: list, photo_dir: str) -> np.ndarray:
  """Camera-to-world [N, 3, 4] (OpenCV axes) of the photos named, from LLFF's poses_bounds.npy (its rows in the
  sorted name order of photo_dir's photos) or an IDR cameras_sphere.npz (DTU: photo NNNNNN.png is camera NNNNNN)."""
  if reference.endswith('.npz'):
    projections = dtu.idr_projections(os.path.dirname(reference), 1 + max(int(os.path.splitext(n)[0]) for n in names))
    return np.stack([algebra.projection_to_camtoworld(projections[int(os.path.splitext(n)[0])])[1] for n in names])
  order, rows = sorted(photos.list_photos(photo_dir)[0]), np.load(reference)
  if len(rows) != len(order):
    raise CaptureError(f'{reference!r} has {len(rows)} cameras for the {len(order)} photos of {photo_dir!r}; expected '
                       'one row per photo, in sorted name order')
  return poses.llff_cameras(rows)[[order.index(n) for n in names]]


def errors(capture_dir: str, reference: str, photo_dir: str) -> dict:
  """Median and largest rotation (degrees) and position (fraction of the camera distance) errors of the capture's
  sparse/0 against the reference cameras (reference_cameras)."""
  names, c2w = poses.model_cameras(colmap_model.read_model(os.path.join(capture_dir, 'sparse', '0')))
  found = poses.pose_errors(c2w, reference_cameras(reference, names, photo_dir))
  return {f'{stat}_{key}': float(fn(found[key])) for stat, fn in (('median', np.median), ('max', np.max))
          for key in ('rotation_deg', 'position')}


def run(args, matching: str) -> dict:
  """One run of the tool with matching: its report's numbers, the errors, CPU seconds and the load around it."""
  scene = os.path.basename(os.path.dirname(os.path.abspath(args.reference)))
  out = os.path.join(args.work, f'{scene}_{matching}')
  load_before, cpu = os.getloadavg(), cpu_seconds()
  pipeline.make(pipeline.Options(args.photos, out, max_size=args.max_size, matching=matching, overwrite=True),
                cli.command_line('tools.capture.bench'))  # The report names the command that made the capture.
  cpu, load_after = cpu_seconds() - cpu, os.getloadavg()
  with open(os.path.join(out, 'report.json'), encoding='utf-8') as f:
    report = json.load(f)
  seconds, n = report['seconds'], report['photos']
  row = {'matching': matching, 'capture': out, 'photos': n, 'registered': report['registered'],
         'models': report['models'], 'points': report['points'],
         'reprojection_error_px': report['reprojection_error_px'], 'seconds': seconds, 'cpu_seconds': cpu,
         'seconds_per_photo': {k: seconds[k] / n for k in ('extraction', 'matching', 'mapping')},
         'load_average_1min': {'before': load_before[0], 'after': load_after[0]},
         'flagged_few_points': next((f['images'] for f in report['flags'] if f['check'] == 'few_points'), []),
         **errors(out, args.reference, args.photos)}
  row['targets_met'] = {'all_registered': row['registered'] == n,
                        'median_rotation_deg': row['median_rotation_deg'] <= TARGETS['median_rotation_deg'],
                        'median_position': row['median_position'] <= TARGETS['median_position'],
                        'total_seconds': seconds['total'] <= TARGETS['total_seconds']}
  return row


def table(rows: list) -> str:
  """The Markdown table of the runs."""
  head = ('| matching | registered | median / max rotation error | median / max position error | flagged: few points '
          '| total s (CPU s) | s per photo: extraction, matching, mapping | load before, after |\n'
          '|---|---|---|---|---|---|---|---|\n')
  return head + ''.join(
      f'| {r["matching"]} | {r["registered"]} of {r["photos"]} | {r["median_rotation_deg"]:.2f} / '
      f'{r["max_rotation_deg"]:.2f} deg | {100 * r["median_position"]:.1f} / {100 * r["max_position"]:.1f} % | '
      f'{", ".join(r["flagged_few_points"]) or "none"} | {r["seconds"]["total"]:.0f} ({r["cpu_seconds"]:.0f}) | '
      + ', '.join(f'{v:.2f}' for v in r['seconds_per_photo'].values())
      + f' | {r["load_average_1min"]["before"]:.1f}, {r["load_average_1min"]["after"]:.1f} |\n' for r in rows)


def markdown(record: dict) -> str:
  """The results as Markdown: the command and its provenance, the table, the targets met."""
  machine = record['machine']
  met = '; '.join(f'{r["matching"]}: ' + ', '.join(f'{k} {"met" if v else "MISSED"}'
                                                   for k, v in r['targets_met'].items()) for r in record['runs'])
  return (f'# tools.capture on {record["runs"][0]["photos"]} photos against independent cameras\n\n'
          f'`{record["command"]}` at commit {record["commit"][:12]}, pycolmap {record["pycolmap"]}, '
          f'{machine["cpu_count"]} CPUs ({machine["platform"]}), shared with other jobs: the 1-minute load average '
          'before and after each run is in the table (above 2, other jobs had the cores too).\n\n'
          'Errors: the recovered cameras against the reference after the similarity alignment of '
          'internal/cameras/alignment.py (one fit of the centres and orientations together); positions as a fraction '
          "of the reference's camera distance. Seconds are wall seconds from the tool's report; CPU seconds are the whole "
          f'run\'s.\n\n{table(record["runs"])}\nTargets ({record["targets"]}): {met}.\n')


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('photos', help='the folder of photos')
  parser.add_argument('--reference', required=True, help="LLFF's poses_bounds.npy of the same photos, or an IDR "
                      'cameras_sphere.npz (DTU)')
  parser.add_argument('--out', required=True, help='the results file to write (.json; a .md beside it)')
  parser.add_argument('--work', default='out/capture', help='where the captures go (kept for training)')
  parser.add_argument('--matching', nargs='+', choices=sfm.MATCHING, default=list(sfm.MATCHING))
  parser.add_argument('--max_size', type=int, default=pipeline.MAX_SIZE)
  args = parser.parse_args(argv)
  rows = [run(args, matching) for matching in args.matching]
  record = {'command': cli.command_line('tools.capture.bench', argv),
            'commit': provenance.git_commit(pipeline.REPO), 'machine': provenance.machine(),
            'pycolmap': sfm.require_pycolmap().__version__, 'targets': TARGETS, 'runs': rows}
  os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
  atomic.write_text(args.out, json.dumps(record, indent=1))
  atomic.write_text(os.path.splitext(args.out)[0] + '.md', markdown(record))
  print(table(rows))
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
