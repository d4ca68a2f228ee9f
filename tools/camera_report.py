"""Camera refinement's report: pictures of the refined cameras of runs, and what a study's results say about the
refinement targets.

Usage: python -m tools.camera_report --out DIR [--runs RUN_DIR ...] [--study RESULTS_CSV [--axis noise
                                      --clean exact --noisy 5deg --baseline freenerf]]

--runs: for each run that refined its cameras (<run>/cameras/cameras.json, internal/run/camera_export.py) writes
DIR/cameras_<name>.png, name the run's study cell (or its folder): the given (before) and refined (after) cameras
carried onto the reference (exact, or the all-photo model's) by their best similarity, with the reference, from above
and from the side as tools.capture's camera picture frames them (tools/capture/picture.view_axes); each camera is its
centre and its viewing ray out to the depth of the scene's middle, so that a few degrees show as the rays' ends
apart; the title gives the median errors before and after.
--study: a study's results.csv (tools.study); writes DIR/targets.md with provenance: per method and seed, the
median camera errors on the noisy cameras and the share of the baseline's noise cost in PSNR (clean - noisy) that
the method recovers on the noisy cameras, (method - baseline) / (baseline clean - baseline noisy), with its mean;
where the study's run folders sit beside the results.csv, also each refining run's rotation error without a
similarity and the mean turn of its given cameras, which that error keeps (unaligned_errors).
Bad input is one line (exit status 2).
"""

import argparse
import csv
import json
import os
import sys

import gin
import matplotlib.figure
import numpy as np
from scipy.spatial import transform as spatial_transform

from internal import cli
from internal import config_loader
from internal import datasets
from internal.datasets import camera_alignment, loader
from internal.evaluation import camera_evaluation
from internal.run import camera_export
from tools import provenance
from tools.capture import picture

# (set, colour, line style, legend) of the cameras drawn.
SETS = (('reference', '0.5', '-', 'reference (exact or all-photo)'), ('given', 'tab:red', '--', 'given (before)'),
        ('refined', 'tab:green', '-', 'refined (after)'))


def run_name(run_dir: str) -> str:
  """A study cell's folder name (its run is <cell>/run), else the run folder's."""
  path = os.path.normpath(run_dir)
  return os.path.basename(os.path.dirname(path) if os.path.basename(path) == 'run' else path)


def _saved_cameras(run_dir: str) -> tuple:
  """(cameras.json's record, the run's Config, its training split) of a run that refined its cameras."""
  path = os.path.join(run_dir, camera_export.FOLDER, 'cameras.json')
  if not os.path.isfile(path):
    raise ValueError(f'{path!r} does not exist: {run_dir!r} is not a run that refined its cameras '
                     '(Config.optimize_cameras) or has not finished training')
  with open(path) as f:
    record = json.load(f)
  gin.clear_config()  # Each run's own settings, not the previous run's.
  config = config_loader.load_config([os.path.join(run_dir, 'config.gin')], [])
  return record, config, datasets.load_dataset('train', config)


def run_cameras(run_dir: str) -> dict:
  """{'reference', 'given', 'refined'}: [N,3,4] cameras of a run's training views, the given and refined ones
  carried onto the reference by their best similarity; 'distance': the reference's camera distance; 'forward'."""
  record, config, train_set = _saved_cameras(run_dir)
  reference, distance = camera_evaluation.reference_cameras(config, train_set)
  cameras = {'reference': reference, 'distance': distance, 'opengl': record['axes'] == 'OpenGL',
             'forward': bool(loader.ray_space(config, train_set).ndc_focal)}
  for name in ('given', 'refined'):
    c2w = np.array(record[name])
    cameras[name] = camera_alignment.fit(c2w, reference).cameras(c2w)
  return cameras


def turns(cameras: np.ndarray, reference: np.ndarray) -> np.ndarray:
  """[N,3] rotation vectors (radians, world axes) that turn the reference's orientations [N,3,4] into cameras'."""
  relative = np.asarray(cameras, np.float64)[:, :, :3] @ np.swapaxes(np.asarray(reference)[:, :, :3], 1, 2)
  return spatial_transform.Rotation.from_matrix(relative).as_rotvec()


def unaligned_errors(run_dir: str) -> dict:
  """Without a similarity (where the reference is exact, the generated scene): {'rotation_deg': the median angle
  of a run's refined training cameras from the reference, 'common_turn_deg': the angle of the mean turn of its given
  cameras, which refinement keeps (its corrections have mean zero: training/camera_refinement.py's gauge)}."""
  record, config, train_set = _saved_cameras(run_dir)
  reference, _ = camera_evaluation.reference_cameras(config, train_set)
  refined, given = (turns(np.array(record[name]), reference) for name in ('refined', 'given'))
  return {'rotation_deg': float(np.rad2deg(np.median(np.linalg.norm(refined, axis=1)))),
          'common_turn_deg': float(np.rad2deg(np.linalg.norm(given.mean(0))))}


def draw(path: str, cameras: dict, title: str) -> None:
  """Writes the picture of run_cameras' sets to path: from above, from the side, and each view's rotation error
  before and after."""
  fig = matplotlib.figure.Figure(figsize=(16, 5.5))
  axes = fig.subplots(1, 3, gridspec_kw={'width_ratios': [1, 1, .8]})
  reference = cameras['reference']
  looks = -1. if cameras['opengl'] else 1.  # OpenGL cameras look down their -z axis, OpenCV's down +z.
  for ax, (label, projection) in zip(axes, picture.view_axes(reference, cameras['forward']).items()):
    for name, colour, style, legend in SETS:
      c2w = cameras[name]
      centres = c2w[:, :, 3]
      ends = centres + looks * cameras['distance'] * c2w[:, :, 2]
      for centre, end in zip(centres @ projection.T, ends @ projection.T):
        ax.plot(*np.stack([centre, end]).T, color=colour, lw=1.2 if name == 'reference' else .9, linestyle=style)
      ax.scatter(*(centres @ projection.T).T, color=colour, s=14, label=legend)
    ax.set_aspect('equal', adjustable='datalim')
    ax.set_title(f'from {"above" if label == "top" else "the side"}', fontsize=10)
  axes[0].legend(loc='upper right', fontsize=8)
  views = np.arange(len(reference))
  for offset, (name, colour, _, legend) in zip((-.2, .2), SETS[1:]):
    values = camera_alignment.errors(cameras[name], reference, cameras['distance'])['rotation_deg']
    axes[2].bar(views + offset, values, width=.4, color=colour, label=legend)
  axes[2].set_xlabel('training view')
  axes[2].set_ylabel('rotation error (degrees)')
  axes[2].legend(fontsize=8)
  fig.suptitle(title, fontsize=11)
  fig.savefig(path, dpi=100)


def errors_title(name: str, cameras: dict) -> str:
  """The picture's title: the run and the median rotation and translation errors before and after."""
  parts = []
  for label in ('given', 'refined'):
    values = camera_alignment.errors(cameras[label], cameras['reference'], cameras['distance'])
    parts.append(f'{label} {np.median(values["rotation_deg"]):.2f} deg, {np.median(values["translation"]):.3f}')
  return f'{name}: median errors against the reference, ' + '; '.join(parts) + ' (of the camera distance)'


def _rows(path: str) -> list:
  """The finished rows of a study's results.csv."""
  with open(path, newline='') as f:
    return [row for row in csv.DictReader(f) if row.get('status') == 'done']


def targets(rows: list, axis: str, clean: str, noisy: str, baseline: str, unaligned=None) -> list:
  """[(method, seed, camera_rotation_deg, camera_translation, psnr, recovered share, rotation without a similarity,
  the common turn it keeps)] on the noisy cameras; unaligned: {cell: unaligned_errors} (nan where absent)."""
  psnr = {(r['method'], r[axis], r['seed']): float(r['psnr']) for r in rows}
  out = []
  for r in rows:
    if r[axis] != noisy:
      continue
    key = (baseline, noisy, r['seed'])
    cost = psnr.get((baseline, clean, r['seed']), np.nan) - psnr.get(key, np.nan)
    share = (float(r['psnr']) - psnr.get(key, np.nan)) / cost if cost else np.nan
    frame = (unaligned or {}).get(r.get('cell'), {})
    out.append((r['method'], int(r['seed']), float(r['camera_rotation_deg'] or 'nan'),
                float(r['camera_translation'] or 'nan'), float(r['psnr']), share,
                frame.get('rotation_deg', np.nan), frame.get('common_turn_deg', np.nan)))
  return sorted(out)


def study_unaligned(results_csv: str, rows: list, axis: str, noisy: str) -> dict:
  """{cell: unaligned_errors} of the refining runs on the noisy cameras whose run folders sit beside results_csv
  (a study's folder: <cell>/run; an export has none)."""
  found = {}
  for r in rows:
    run_dir = os.path.join(os.path.dirname(results_csv), r.get('cell', ''), 'run')
    if r[axis] == noisy and os.path.isfile(os.path.join(run_dir, camera_export.FOLDER, 'cameras.json')):
      found[r['cell']] = unaligned_errors(run_dir)
  return found


def targets_markdown(found: list, args, argv) -> str:
  """targets.md: a row per method and seed, each method's means, and the provenance."""
  lines = [f'On the {args.noisy!r} cameras of {args.study}; the share is (method - {args.baseline}) / '
           f'({args.baseline} {args.clean} - {args.baseline} {args.noisy}) in PSNR, per seed. Camera errors are '
           'medians over the training views after the similarity that best maps them onto the reference (the '
           'target\'s); without it (the generated scene\'s frame is exact) the refined cameras keep the mean turn of '
           'the given ones, which the corrections\' gauge leaves (nan: a run without refined cameras here).', '',
           '| method | seed | camera rotation error (deg, median) | camera translation error (median) | PSNR | '
           'share of the noise cost recovered | rotation error without the similarity (deg, median) | '
           'mean turn of the given cameras (deg) |', '|---|---|---|---|---|---|---|---|']
  lines += [f'| {m} | {s} | {r:.3f} | {t:.4f} | {p:.3f} | {share:.2f} | {u:.3f} | {c:.3f} |'
            for m, s, r, t, p, share, u, c in found]
  lines += ['', '| method | mean rotation error (deg) | mean translation error | mean PSNR | mean share | '
            'mean rotation error without the similarity (deg) | mean turn of the given cameras (deg) |',
            '|---|---|---|---|---|---|---|']
  for method in sorted({f[0] for f in found}):
    values = np.array([f[2:] for f in found if f[0] == method])
    lines.append(f'| {method} | ' + ' | '.join(f'{v:.3f}' for v in values.mean(0)) + ' |')
  return '\n'.join(lines + ['', '```json', json.dumps(provenance.record(['python', '-m', 'tools.camera_report',
                                                                         *argv]), indent=1), '```', ''])


def main(argv=None) -> int:
  argv = sys.argv[1:] if argv is None else argv
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--out', required=True, help='folder to write into')
  parser.add_argument('--runs', nargs='*', default=[], help="run directories (a study cell's <cell>/run)")
  parser.add_argument('--study', help="a study's results.csv")
  parser.add_argument('--axis', default='noise', help='the study axis of the camera noise')
  parser.add_argument('--clean', default='exact', help='its label without noise')
  parser.add_argument('--noisy', default='5deg', help='its label with the noise of the targets')
  parser.add_argument('--baseline', default='freenerf', help='the method without refinement')
  args = parser.parse_args(argv)
  os.makedirs(args.out, exist_ok=True)
  for run_dir in args.runs:
    cameras = run_cameras(run_dir)
    path = os.path.join(args.out, f'cameras_{run_name(run_dir)}.png')
    draw(path, cameras, errors_title(run_name(run_dir), cameras))
    print(path)
  if args.study:
    if not os.path.isfile(args.study):
      raise FileNotFoundError(f'--study {args.study!r} does not exist; expected a study\'s results.csv')
    path = os.path.join(args.out, 'targets.md')
    rows = _rows(args.study)
    unaligned = study_unaligned(args.study, rows, args.axis, args.noisy)
    with open(path, 'w', encoding='utf-8') as f:
      f.write(targets_markdown(targets(rows, args.axis, args.clean, args.noisy, args.baseline, unaligned), args,
                               argv))
    print(path)
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
