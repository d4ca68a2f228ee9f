"""Camera refinement's report: pictures of the refined cameras of runs, and what a study's results say about the
refinement targets.

Usage: python -m lab.camera_report --out DIR [--runs RUN_DIR ... [--modes]] [--study RESULTS_CSV [--axis noise
                                      --clean exact --noisy 5deg --baseline freenerf --psnr psnr
                                      --methods M ... --name FILE]]

--runs: for each run that refined its cameras (<run>/cameras/cameras.json, internal/run/camera_export.py) writes
DIR/cameras_<name>.png, name the run's study cell (or its folder): the given (before) and refined (after) cameras
carried onto the reference (exact, or the all-photo model's) by their best similarity, with the reference, from above
and from the side as tools.capture's camera picture frames them (tools/capture/picture.view_axes); each camera is its
centre and its viewing ray out to the depth of the scene's middle, so that a few degrees show as the rays' ends
apart; the title gives the median errors before and after.
--modes: also DIR/camera_modes.md with provenance: per run, the given and refined cameras' rotation errors (after the
similarity) in each camera's own axes, the turn that the views share there (their mean: a common tilt, which the
similarity cannot take up and an image sees mostly as the scene moved) and the median error with that turn taken out.
--study: a study's results.csv (lab.study); writes DIR/targets.md with provenance: per method and seed, the
median camera errors on the noisy cameras and the share of the baseline's noise cost in PSNR (clean - noisy) that
the method recovers on the noisy cameras, (method - baseline) / (baseline clean - baseline noisy), with its mean;
--psnr names the PSNR column (psnr@test_pose: under BARF's test-time pose optimization, lab/study/evaluations.py;
written as DIR/targets_<column>.md, so that both protocols' targets stand side by side; --name another file name);
--methods keeps the rows of those methods and the baseline (a study whose methods differ in scale, each with its own
baseline);
where the method also ran on the clean cameras, its drift there (their median rotation error).
The camera errors of the targets are after the similarity (camera_rotation_deg, camera_translation): a similarity
explains part of any error, so a target on them is met only under that alignment; where the results hold the
errors without it (cameras in the reference's frame: *_unaligned), their means follow.
Bad input is one line (exit status 2), before anything is written: a study without the --axis column, a --clean,
--noisy or --baseline that no finished row has, two --runs whose pictures would have one name.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import csv
import json
import os
import sys

import matplotlib.figure
import numpy as np

from internal import cli
from internal import runs
from tools import provenance
from tools.capture import picture

# (set, colour, line style, legend) of the cameras drawn.
SETS = (('reference', '0.5', '-', 'reference (exact or all-photo)'), ('given', 'tab:red', '--', 'given (before)'),
        ('refined', 'tab:green', '-', 'refined (after)'))


def run_name(run_dir: str) -> str:
  """A study cell's folder name (its run is <cell>/run), else the run folder's."""
  path = os.path.normpath(run_dir)
  return os.path.basename(os.path.dirname(path) if os.path.basename(path) == 'run' else path)


def run_cameras(run_dir: str) -> dict:
  """{'reference', 'given', 'refined'}: [N,3,4] cameras of a run's training views, the given and refined ones
  carried onto the reference by their best similarity; 'distance': the reference's camera distance; 'forward'."""
  path = runs.cameras_file(run_dir)
  if not os.path.isfile(path):
    raise ValueError(f'{path!r} does not exist: {run_dir!r} is not a run that refined its cameras '
                     '(Config.optimize_cameras) or has not finished training')
  with open(path) as f:
    record = json.load(f)
  with runs.run_config(run_dir) as config:  # Each run's own settings, not the previous run's.
    train_set = runs.training_views(config)
    reference, distance, _ = runs.reference_cameras(config, train_set)
  cameras = {'reference': reference, 'distance': distance, 'opengl': record['axes'] == 'OpenGL',
             'forward': bool(train_set.space.ndc_focal)}
  for name in ('given', 'refined'):
    c2w = np.array(record[name])
    cameras[name] = runs.similarity(c2w, reference).cameras(c2w)
  return cameras


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
    values = runs.camera_errors(cameras[name], reference, cameras['distance'])['rotation_deg']
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
    values = runs.camera_errors(cameras[label], cameras['reference'], cameras['distance'])
    parts.append(f'{label} {np.median(values["rotation_deg"]):.2f} deg, {np.median(values["translation"]):.3f}')
  return f'{name}: median errors against the reference, ' + '; '.join(parts) + ' (of the camera distance)'


def _rows(path: str) -> list:
  """The finished rows of a study's results.csv."""
  with open(path, newline='') as f:
    return [row for row in csv.DictReader(f) if row.get('status') == 'done']


def check_study(rows: list, path: str, axis: str, clean: str, noisy: str, baseline: str, psnr: str) -> None:
  """ValueError naming the flag whose column or label the study's finished rows lack (a study without the noise
  axis, a noise label or baseline that no row has), or naming the file when no row finished."""
  if not rows:
    raise ValueError(f'--study {path!r}: no finished row (status done); expected a study\'s results.csv')
  if axis not in rows[0]:
    raise ValueError(f'--axis {axis!r}: --study {path!r} has no such column; expected the study axis of the camera '
                     f'noise among its columns {sorted(rows[0])}')
  missing = [c for c in ('method', 'seed', psnr) if c not in rows[0]]
  if missing:
    raise ValueError(f'--study {path!r} has no column {missing[0]!r}; expected a study with seeds whose results '
                     f'give method, seed and {psnr} (--psnr)')
  labels, methods = sorted({r[axis] for r in rows}), sorted({r['method'] for r in rows})
  for flag, value, known in (('--clean', clean, labels), ('--noisy', noisy, labels), ('--baseline', baseline, methods)):
    if value not in known:
      raise ValueError(f'{flag} {value!r}: no finished row of --study {path!r} has it; expected one of {known}')


def targets(rows: list, axis: str, clean: str, noisy: str, baseline: str, column: str = 'psnr') -> list:
  """[(method, seed, camera_rotation_deg, camera_translation, PSNR, recovered share, drift)] on the noisy cameras:
  PSNR of the column given, drift the method's rotation error on the clean cameras (nan where it has none)."""
  psnr = {(r['method'], r[axis], r['seed']): float(r[column] or 'nan') for r in rows}
  rotation = {(r['method'], r[axis], r['seed']): float(r.get('camera_rotation_deg') or 'nan') for r in rows}
  out = []
  for r in rows:
    if r[axis] != noisy:
      continue
    key = (baseline, noisy, r['seed'])
    cost = psnr.get((baseline, clean, r['seed']), np.nan) - psnr.get(key, np.nan)
    share = (psnr[r['method'], noisy, r['seed']] - psnr.get(key, np.nan)) / cost if cost else np.nan
    out.append((r['method'], int(r['seed']), rotation[r['method'], noisy, r['seed']],
                float(r.get('camera_translation') or 'nan'), psnr[r['method'], noisy, r['seed']], share,
                rotation.get((r['method'], clean, r['seed']), np.nan)))
  return sorted(out)


def check_runs(run_dirs: list) -> None:
  """ValueError naming two --runs whose pictures would have the same name (the second would replace the first)."""
  seen = {}
  for run_dir in run_dirs:
    name = run_name(run_dir)
    if name in seen:
      raise ValueError(f'--runs {seen[name]!r} and {run_dir!r} are both named {name!r} (a study cell\'s folder, or '
                       f'the run\'s): both pictures would be cameras_{name}.png; give them in separate commands with '
                       'another --out')
    seen[name] = run_dir


def unaligned_means(rows: list, axis: str, noisy: str) -> dict:
  """{method: (mean rotation error (deg), mean translation error)} without the similarity on the noisy cameras,
  of the methods whose results hold them."""
  out = {}
  for method in sorted({r['method'] for r in rows}):
    values = [(float(r['camera_rotation_deg_unaligned']), float(r['camera_translation_unaligned'])) for r in rows
              if r['method'] == method and r[axis] == noisy and r.get('camera_rotation_deg_unaligned')]
    if values:
      out[method] = tuple(np.mean(values, 0))
  return out


def targets_markdown(found: list, args, argv, unaligned: dict) -> str:
  """targets.md: a row per method and seed, each method's means (and unaligned_means'), and the provenance."""
  lines = [f'On the {args.noisy!r} cameras of {cli.relative_paths(args.study)}; the share is (method - '
           f'{args.baseline}) / ({args.baseline} {args.clean} - {args.baseline} {args.noisy}) in PSNR (`{args.psnr}`), '
           'per seed. Camera errors are '
           'medians over the training views against the reference after the similarity taking the cameras onto it '
           '(camera_rotation_deg, camera_translation): the alignment the targets use; the drift is the same '
           f'method\'s rotation error on the {args.clean!r} cameras (blank where it did not run there).', '',
           f'| method | seed | camera rotation error (deg, median) | camera translation error (median) | {args.psnr} | '
           f'share of the noise cost recovered | drift on {args.clean} cameras (deg) |', '|---|---|---|---|---|---|---|']
  lines += [f'| {m} | {s} | {r:.3f} | {t:.4f} | {p:.3f} | {share:.2f} | {_blank(drift)} |'
            for m, s, r, t, p, share, drift in found]
  lines += ['', f'| method | mean rotation error (deg) | mean translation error | mean {args.psnr} | mean share | '
            'mean drift (deg) |', '|---|---|---|---|---|---|']
  for method in sorted({f[0] for f in found}):
    values = np.array([f[2:] for f in found if f[0] == method])
    lines.append(f'| {method} | ' + ' | '.join(_blank(v) for v in values.mean(0)) + ' |')
  if unaligned:
    lines += ['', 'Without the similarity (the cameras in the reference\'s frame):', '',
              '| method | mean rotation error (deg) | mean translation error |', '|---|---|---|']
    lines += [f'| {method} | {r:.3f} | {t:.4f} |' for method, (r, t) in unaligned.items()]
  return '\n'.join(lines + ['', '```json', json.dumps(provenance.record(['python', '-m', 'lab.camera_report',
                                                                         *argv]), indent=1), '```', ''])


def modes_row(name: str, cameras: dict, label: str) -> str:
  """camera_modes.md's row of one set of run_cameras: the shared turn (x, y, z, its angle), the median error, the
  median error without the shared turn (degrees)."""
  turns = runs.own_axes_turns(cameras[label], cameras['reference'])
  shared = turns.mean(0)
  medians = [np.median(np.linalg.norm(t, axis=1)) for t in (turns, turns - shared)]
  return (f'| {name} | {label} | ' + ' | '.join(f'{v:+.3f}' for v in shared) + f' | {np.linalg.norm(shared):.3f} | '
          + ' | '.join(f'{v:.3f}' for v in medians) + ' |')


def modes_markdown(rows: list, argv) -> str:
  """camera_modes.md: the rows of modes_row under their header, and the provenance."""
  lines = ['Rotation errors of the training cameras against the reference after the similarity, in each camera\'s own '
           'axes (x right, y up, z along its axis; degrees): the turn every view shares (their mean) and the median '
           'error with and without it.', '',
           '| run | cameras | shared turn x | shared turn y | shared turn z | shared turn (deg) | median error (deg) | '
           'median error without the shared turn (deg) |', '|---|---|---|---|---|---|---|---|'] + rows
  return '\n'.join(lines + ['', '```json', json.dumps(provenance.record(['python', '-m', 'lab.camera_report', *argv]),
                                                      indent=1), '```', ''])


def _blank(value: float) -> str:
  """A number with 3 decimals, '' for nan (a value the study does not hold)."""
  return '' if np.isnan(value) else f'{value:.3f}'


def main(argv=None) -> int:
  argv = sys.argv[1:] if argv is None else argv
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--out', required=True, help='folder to write into')
  parser.add_argument('--runs', nargs='*', default=[], help="run directories (a study cell's <cell>/run)")
  parser.add_argument('--methods', nargs='+', help='with --study: only these methods\' rows (and the baseline\'s)')
  parser.add_argument('--name', help='with --study: the targets file\'s name in --out (default targets.md, or '
                      'targets_<--psnr>.md)')
  parser.add_argument('--modes', action='store_true', help='with --runs: camera_modes.md, the turn the views share '
                      'in their own axes')
  parser.add_argument('--study', help="a study's results.csv")
  parser.add_argument('--axis', default='noise', help='the study axis of the camera noise')
  parser.add_argument('--clean', default='exact', help='its label without noise')
  parser.add_argument('--noisy', default='5deg', help='its label with the noise of the targets')
  parser.add_argument('--baseline', default='freenerf', help='the method without refinement')
  parser.add_argument('--psnr', default='psnr', help='the PSNR column of the share (psnr@test_pose: after '
                      'test-time pose optimization, where the study evaluated it)')
  args = parser.parse_args(argv)
  check_runs(args.runs)
  rows = _study_rows(args)
  os.makedirs(args.out, exist_ok=True)
  modes = []
  for run_dir in args.runs:
    cameras = run_cameras(run_dir)
    path = os.path.join(args.out, f'cameras_{run_name(run_dir)}.png')
    draw(path, cameras, errors_title(run_name(run_dir), cameras))
    print(path)
    modes += [modes_row(run_name(run_dir), cameras, label) for label in ('given', 'refined')]
  if args.modes and modes:
    path = os.path.join(args.out, 'camera_modes.md')
    with open(path, 'w', encoding='utf-8') as f:
      f.write(modes_markdown(modes, argv))
    print(path)
  if args.study:
    path = os.path.join(args.out, args.name or ('targets.md' if args.psnr == 'psnr' else f'targets_{args.psnr}.md'))
    with open(path, 'w', encoding='utf-8') as f:
      f.write(targets_markdown(targets(rows, args.axis, args.clean, args.noisy, args.baseline, args.psnr), args, argv,
                               unaligned_means(rows, args.axis, args.noisy)))
    print(path)
  return 0


def _study_rows(args) -> list:
  """The finished rows of --study, checked against --axis, --clean, --noisy and --baseline ([] without --study)."""
  if not args.study:
    return []
  if not os.path.isfile(args.study):
    raise FileNotFoundError(f'--study {args.study!r} does not exist; expected a study\'s results.csv')
  rows = _rows(args.study)
  check_study(rows, args.study, args.axis, args.clean, args.noisy, args.baseline, args.psnr)
  unknown = sorted(set(args.methods or ()) - {r['method'] for r in rows})
  if unknown:
    raise ValueError(f'--methods {unknown}: no finished row of --study {args.study!r} has them')
  return [r for r in rows if not args.methods or r['method'] in set(args.methods) | {args.baseline}]


if __name__ == '__main__':
  sys.exit(cli.run(main))
