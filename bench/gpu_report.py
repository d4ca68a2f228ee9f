"""The tables of a bench/gpu_check.sh run: step variants, kernel profiles and the precision trade, and a picture.

Usage: python -m bench.gpu_report OUT_DIR

Reads what gpu_check.sh left in OUT_DIR (stages.tsv, step_variants.json, train_<run>.log, metrics_<run>.json,
test_preds_<run>/, test_truth/) and writes gpu_report.md (printed too) and test_views.png (a column per test view;
the ground truth, then per run a colour and a depth row). A run is METHOD_PRECISION[_VARIANT] (the step variant it
trained with); its step time is the training's own rate once warm, its minutes the training stage's wall time
(start-up and compilation included), its paper-length minutes 43,945 steps at that rate.
"""

import csv
import glob
import json
import os
import re
import sys

import numpy as np
from PIL import Image

from bench import step_variants
from internal import cli
from internal import demo
from internal.datasets import image_io
from internal.datasets import packed
from internal.evaluation import vis

PAPER_DTU_STEPS = 43945
VIEWS_IN_PICTURE = 3
KINDS = {'color_': 'colour', 'depth_': 'depth'}  # A run's rows in test_views.png: file prefix -> row label.
TRUTH_FOLDER = 'test_truth'  # The pictured views' ground truth in OUT_DIR (write_truth).


def stage_seconds(out_dir: str):
  """{stage: (last status, seconds)} of stages.tsv; a stage listed again (a run resumed by a later call, its
  stages.tsv appended) adds its seconds."""
  stages = {}
  with open(os.path.join(out_dir, 'stages.tsv')) as f:
    for name, status, seconds in csv.reader(f, delimiter='\t'):
      stages[name] = (status, stages.get(name, (None, 0.))[1] + float(seconds))
  return stages


def step_rate(log_text: str):
  """(last step, steps per second) of a training log's progress lines, or (0, None) when it has none."""
  steps = re.findall(r'(\d+)/\d+ \[', log_text)
  rates = re.findall(r'([\d.]+)(step/s|s/step)', log_text)
  if not rates:
    return (int(steps[-1]) if steps else 0), None
  value, unit = rates[-2] if len(rates) > 1 else rates[-1]  # The last line's rate averages in the tail.
  return int(steps[-1]), float(value) if unit == 'step/s' else 1 / float(value)


def trade_rows(out_dir: str):
  """One dict per run of the precision trade, in the order the runs ran."""
  stages = stage_seconds(out_dir)
  rows = []
  for name, (status, seconds) in stages.items():
    if not name.startswith('train_'):
      continue
    run = name[len('train_'):]
    method, precision, *variant = run.split('_', 2)
    log = os.path.join(out_dir, f'{name}.log')
    last, rate = step_rate(open(log).read()) if os.path.isfile(log) else (0, None)
    metrics_file = os.path.join(out_dir, f'metrics_{run}.json')
    means = json.load(open(metrics_file))['means'] if os.path.isfile(metrics_file) else {}
    rows.append({'run': run, 'method': method, 'precision': precision, 'variant': (variant or ['base'])[0],
                 'status': status, 'steps': last,
                 'step_ms': 1e3 / rate if rate else None, 'minutes': seconds / 60,
                 'paper_minutes': PAPER_DTU_STEPS / rate / 60 if rate else None, **means})
  return rows


def _cell(value, spec):
  return '' if value is None else format(value, spec)


def trade_table(rows) -> str:
  """Markdown of trade_rows."""
  lines = ['| precision | method | variant | steps | step ms | minutes | paper-length min | PSNR | SSIM | '
           'object PSNR | object SSIM |', '|---|---|---|---|---|---|---|---|---|---|---|']
  for r in rows:
    head = f"| {r['precision']} | {r['method']} | {r['variant']} |"
    if r['status'] == 'skipped':
      lines.append(f'{head} not run: the budget ran out |' + ' |' * 7)
      continue
    lines.append(f"{head} {r['steps']} | {_cell(r['step_ms'], '.1f')} | "
                 f"{r['minutes']:.1f} | {_cell(r['paper_minutes'], '.1f')} | {_cell(r.get('psnr'), '.2f')} | "
                 f"{_cell(r.get('ssim'), '.3f')} | {_cell(r.get('psnr_masked'), '.2f')} | "
                 f"{_cell(r.get('ssim_masked'), '.3f')} |")
  return '\n'.join(lines)


def write_truth(packed_scene: str, out_dir: str) -> int:
  """Writes the ground truth of the test views that the runs' renders show (test_preds_<run>/color_<id>.png), read
  from the packed scene they were evaluated on (downsampled to the renders' size, as an eval_factor does), as
  out_dir/test_truth/color_<id>.png; returns how many."""
  meta, arrays = packed.read_pack(packed_scene)
  ids, images = meta['splits']['test']['ids'], packed.decode(arrays, 'test/images')
  renders = {os.path.basename(p): p for p in glob.glob(os.path.join(out_dir, 'test_preds_*', 'color_*.png'))}
  os.makedirs(os.path.join(out_dir, TRUTH_FOLDER), exist_ok=True)
  for name, render in sorted(renders.items()):
    truth = images[ids.index(_view_id(name))]
    factor = truth.shape[0] // _image(render).shape[0]
    vis.save_png(image_io.downsample(truth, factor, 'released'), os.path.join(out_dir, TRUTH_FOLDER, name))
  return len(renders)


def _view_id(name: str) -> int:
  """The test view id of a render's file name (color_011.png -> 11)."""
  return int(name.removeprefix('color_').removesuffix('.png'))


def _image(path: str) -> np.ndarray:
  """A PNG as float RGB [h, w, 3] in [0, 1]."""
  with Image.open(path) as image:
    return np.asarray(image.convert('RGB'), np.float32) / 255.


def picture(out_dir: str, runs) -> str:
  """test_views.png: a column per pictured test view (the first run's first views, by id), a row of their ground
  truth (test_truth/, write_truth) and per run a colour and a depth row, every row and column labelled; '' when no
  run has views."""
  rendered = [sorted(glob.glob(os.path.join(out_dir, f'test_preds_{run}', 'color_*.png'))) for run in runs]
  names = [os.path.basename(p) for p in next((r for r in rendered if r), [])][:VIEWS_IN_PICTURE]
  if not names:
    return ''
  truth = [os.path.join(out_dir, TRUTH_FOLDER, n) for n in names]
  tiles, rows = ([[_image(p) for p in truth]], ['ground truth']) if all(map(os.path.isfile, truth)) else ([], [])
  for run in runs:
    folder = os.path.join(out_dir, f'test_preds_{run}')
    if all(os.path.isfile(os.path.join(folder, n)) for n in names):
      tiles += [[_image(os.path.join(folder, n.replace('color_', kind))) for n in names] for kind in KINDS]
      rows += [f'{run} {label}' for label in KINDS.values()]
  path = os.path.join(out_dir, 'test_views.png')
  columns = [f'test view {_view_id(n)}' for n in names]
  vis.save_picture(demo.grid(tiles, columns, rows, scale=1), path)
  return path


def report(out_dir: str) -> str:
  """The whole report's markdown (variants, profiles, trade)."""
  parts = []
  variants_file = os.path.join(out_dir, 'step_variants.json')
  if os.path.isfile(variants_file):
    variants = json.load(open(variants_file))
    parts += [f"## Step variants ({variants['device']}, jax {variants['jax_version']})\n\n`{variants['command']}`"
              f'\n\n{step_variants.table(variants)}', '## Kernel profiles\n\n' + step_variants.profile_tables(variants)]
  rows = trade_rows(out_dir)
  if rows:
    pictured = [r['run'] for r in rows if os.path.isdir(os.path.join(out_dir, f"test_preds_{r['run']}"))]
    caption = (f'\n\nRows of test_views.png, top to bottom: the ground truth, {", ".join(pictured)} (colour over '
               'depth).'
               if picture(out_dir, pictured) else '')
    parts.append('## Precision trade\n\n' + trade_table(rows) + caption)
  return '\n\n'.join(parts) or f'nothing to report in {out_dir}'


def main(argv=None):
  argv = sys.argv[1:] if argv is None else argv
  if len(argv) != 1 or not os.path.isfile(os.path.join(argv[0], 'stages.tsv')):
    raise ValueError('usage: python -m bench.gpu_report OUT_DIR (a bench/gpu_check.sh output with stages.tsv)')
  text = report(argv[0])
  with open(os.path.join(argv[0], 'gpu_report.md'), 'w') as f:
    f.write(text + '\n')
  print(text)


if __name__ == '__main__':
  sys.exit(cli.run(main))
