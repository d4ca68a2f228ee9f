"""Frames per second of the viewer's live render on this machine, at 1/4, 1/2 and the full size.

Usage: python -m bench.viewer_fps [--repeats 3] [--paper_rows 300] [--out results/viewer/fps.json]

What tools.view renders for a browser (tools/view/frames.render_frame: the camera's rays, the run's render in
chunks, the colour picture), timed from test camera 0, each size's first frame left out (it compiles), the sizes
interleaved so that they share the machine's noise, the median kept:
  demo   the demo's FreeNeRF, its trained run (`python train.py` first): NeRF 4 x 64, 32 + 32 samples a ray, at
         1/4, 1/2 and the full demo test size (64 x 80 at its aspect);
  paper  a paper-size model: mip-NeRF 8 x 256 with 2 x 128 samples a ray (configs/freenerf/dtu3_freenerf.gin's),
         random weights (a frame's time does not depend on them), on the generated object scene's rays, full size
         a paper scene's (--paper_rows, default DTU's 300 x 400 at factor 4). Its larger frames take many minutes
         on a small CPU, so it is timed at 1/16 and 1/8 of that size, and its 1/4, 1/2 and full-size frames are
         extrapolated from the 1/8 frame's seconds per ray (a frame's time grows with its rays: fixed-size chunks),
         marked 'extrapolated'.
Writes --out with provenance, the load average before and after (other programs share a CPU: compare the sizes and
the models with each other rather than with another machine) and the rows that the viewer's 'auto' moving size
picks at the measured speed.
"""

import argparse
import json
import os
import statistics
import sys
import time

import gin
import jax
from jax import random

from internal import atomic
from internal import cli
from internal import config_loader
from internal import datasets
from internal.cameras import algebra
from internal.training import train_step
from tools import provenance
from tools.view import cameras, frames, resolution, runs

SIZES = {'1/4': 1 / 4, '1/2': 1 / 2, 'full': 1.}
PAPER_TIMED = {'1/16': 1 / 16, '1/8': 1 / 8}  # The paper-size model's timed sizes; SIZES are extrapolated.
PAPER = ['MLP.net_depth = 8', 'MLP.net_width = 256', 'MLP.net_width_viewdirs = 128', 'MipNerfModel.num_samples = 128',
         'MipNerfModel.num_levels = 2', 'Config.render_chunk_size = 4096']
DTU_ASPECT = 4 / 3  # A DTU image's width over height.


def random_weights_run(bindings) -> runs.Run:
  """A Run of configs/demo.gin's scene (the generated object scene) with bindings' model at random weights."""
  gin.clear_config()
  config = config_loader.load_config([os.path.join(cli.CONFIG_DIR, 'demo.gin')], bindings)
  train_set, test_set = datasets.load_dataset('train', config), datasets.load_dataset('test', config)
  example = jax.tree.map(lambda x: x[0, 0, :8], train_set.rays)
  model, state = train_step.create_train_state(config, random.PRNGKey(0), example)
  return runs.Run(config, '(random weights)', model, state, train_set, test_set)


def test_view(run: runs.Run, aspect: float) -> frames.View:
  """Test camera 0 of run as a browser of the given aspect sends it."""
  test = run.test_cameras()
  c2w = test.camtoworlds[0]
  return frames.View(tuple(algebra.rotation_to_quaternion(c2w[:, :3])), tuple(c2w[:, 3]),
                     cameras.field_of_view(test.pixtocams[0], test.size[0]), aspect)


def time_sizes(run: runs.Run, view: frames.View, full_rows: int, sizes: dict, repeats: int) -> dict:
  """{size: {'rows', 'width', 'rays', 'seconds' (each timed frame), 'median_seconds', 'fps'}} of sizes {name:
  fraction of full_rows}."""
  rows = {name: max(1, int(round(full_rows * fraction))) for name, fraction in sizes.items()}
  seconds = {name: [] for name in sizes}
  for round_index in range(repeats + 1):  # Round 0 compiles each size's chunks: left out.
    for name, count in rows.items():
      start = time.perf_counter()
      frames.render_frame([run], view, count, frames.Options(full_rows=full_rows))
      if round_index:
        seconds[name].append(round(time.perf_counter() - start, 4))
  out = {}
  for name, count in rows.items():
    width = resolution.frame_width(count, view.aspect)
    median = statistics.median(seconds[name])
    out[name] = {'rows': count, 'width': width, 'rays': count * width, 'seconds': seconds[name],
                 'median_seconds': round(median, 4), 'fps': round(1. / median, 3)}
  return out


def extrapolated(seconds_per_ray: float, full_rows: int, aspect: float) -> dict:
  """{size: {'rows', 'width', 'rays', 'median_seconds', 'fps', 'extrapolated': True}} of SIZES at seconds_per_ray."""
  out = {}
  for name, fraction in SIZES.items():
    rows = max(1, int(round(full_rows * fraction)))
    width = resolution.frame_width(rows, aspect)
    seconds = seconds_per_ray * rows * width
    out[name] = {'rows': rows, 'width': width, 'rays': rows * width, 'median_seconds': round(seconds, 4),
                 'fps': round(1. / seconds, 5), 'extrapolated': True}
  return out


def measure(run: runs.Run, view: frames.View, full_rows: int, repeats: int, what: str, timed=None) -> dict:
  """The record of one model: what it is, its sizes' timings (SIZES timed; or the sizes timed, their last one's
  seconds per ray extrapolated to SIZES) and the 'auto' moving rows at that speed."""
  sizes = time_sizes(run, view, full_rows, timed or SIZES, repeats)
  last = sizes[list(timed or SIZES)[-1]]
  seconds_per_ray = last['median_seconds'] / last['rays']
  if timed:
    sizes.update(extrapolated(seconds_per_ray, full_rows, view.aspect))
  return {'what': what, 'run': run.run_dir, 'step': run.step, 'sizes': sizes, 'seconds_per_ray': seconds_per_ray,
          'auto_moving_rows': resolution.moving_rows('auto', full_rows, seconds_per_ray, view.aspect)}


def main(argv=None) -> int:
  argv = sys.argv[1:] if argv is None else list(argv)
  parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
  parser.add_argument('--repeats', type=int, default=3, help='timed frames of each size (default 3)')
  parser.add_argument('--paper_rows', type=int, default=300, help="the paper-size model's full rows (default 300)")
  parser.add_argument('--out', default=os.path.join('results', 'viewer', 'fps.json'))
  args = parser.parse_args(argv)
  if args.repeats < 1 or args.paper_rows < 16:
    raise ValueError(f'--repeats {args.repeats}, --paper_rows {args.paper_rows}: expected >= 1 and >= 16')
  load_before = os.getloadavg()
  demo = runs.load(cli.DEMO_CONFIGS, [])
  records = {'demo': measure(demo, test_view(demo, demo.test_set.width / demo.test_set.height),
                             demo.test_set.height, args.repeats,
                             "the demo's FreeNeRF (configs/demo.gin + demo_forward.gin), trained")}
  paper = random_weights_run(PAPER)
  records['paper'] = measure(paper, test_view(paper, DTU_ASPECT), args.paper_rows, args.repeats,
                             'mip-NeRF 8 x 256, 2 x 128 samples, random weights, generated object scene rays',
                             timed=PAPER_TIMED)
  record = {'models': records, 'frame_budget_seconds': resolution.FRAME_BUDGET,
            'load_average': {'before': [round(x, 2) for x in load_before],
                             'after': [round(x, 2) for x in os.getloadavg()]},
            'provenance': provenance.record(['python', '-m', 'bench.viewer_fps', *argv])}
  os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
  atomic.write_text(args.out, json.dumps(record, indent=1) + '\n')
  for name, model in records.items():
    print(f'{name}: ' + ', '.join(f'{size} ({s["rows"]} x {s["width"]}) {s["fps"]:.3g} fps'
                                  + (' (extrapolated)' if s.get('extrapolated') else '')
                                  for size, s in model['sizes'].items()) +
          f'; auto moving size {model["auto_moving_rows"]} rows')
  print(f'in {args.out}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
