"""A trained run's field as a point cloud: a PLY and a COLMAP model that splatting trainers start from.

  python -m tools.points --gin_configs=configs/demo.gin --out points.ply [--colmap DIR] [--max_points N]
                         [--path_views K] [--min_opacity 0.95] [--tolerance 0.02] [--min_views 2]

Pass the gin configs and bindings used for training. Every training view is rendered at the training size (and,
with --path_views, K frames of the render path; world-ray scenes only), its expected depth turned into a world
point per pixel (NDC scenes: converted back to the world), kept where the ray is at least --min_opacity opaque and
--min_views training views agree: the point lies in front of them, inside their images, where their own
renderings are opaque at the same camera depth within --tolerance (relative); internal/geometry/points.py.
Each point is coloured by the rendered radiance of its pixel and has the rendered normal where it is known (world
rays; NDC scenes' points have none). --max_points caps the cloud, each view keeping an equal share.

Writes --out (a binary PLY: x y z, nx ny nz where known, red green blue) and, with --colmap DIR, a COLMAP model in
DIR/sparse/0 (binary, or text with --colmap_text): a PINHOLE camera per training image at the size of its file
(the loader's intrinsics without distortion), its pose, the points with their tracks (the agreeing training views,
observed at their projections), and copies of the training image files in DIR/images. It loads with this
project's capture loader (Config.dataset_loader = 'capture', Config.data_dir = DIR) and is what splatting trainers
read as their initialization. The host memory the views and --max_points need, and that every output can be
written, are checked before any work; nothing is replaced unless Config.overwrite = True. On the generated object scene --scores FILE also writes the cloud's
distances to the scene's exact surfaces per solid (as tools.mesh --scores); --picture a PNG of the cloud.
"""

import errno
import json
import os
import shutil
import sys
import tempfile
import time

import jax
import matplotlib.figure
import numpy as np

from internal import atomic
from internal import cli
from internal import datasets
from internal.datasets import colmap_model
from internal.datasets import image_io
from internal.datasets import loader
from internal.datasets import scene_generator
from internal.evaluation import inference
from internal.geometry import mesh_scores
from internal.geometry import ply
from internal.geometry import points as points_lib
from internal.run import checkpoints
from internal.run import out_of_memory
from internal.run import run_dir as run_dir_lib
from tools import mesh as mesh_tool
from tools import provenance


def parse_args(argv):
  parser = cli.flag_parser(__doc__.split('\n')[0])
  parser.add_argument('--out', required=True, help='the PLY file to write')
  parser.add_argument('--colmap', help='also a COLMAP model (sparse/0) and the training images in this folder')
  parser.add_argument('--colmap_text', action='store_true', help='the COLMAP model as text (default: binary)')
  parser.add_argument('--max_points', type=int, default=1000000, help='the most points kept (default 1,000,000)')
  parser.add_argument('--path_views', type=int, default=0, help='also this many frames of the render path')
  parser.add_argument('--min_opacity', type=float, default=.95, help='a pixel\'s opacity to keep its point (0.95)')
  parser.add_argument('--tolerance', type=float, default=.02, help='relative depth agreement (default 0.02)')
  parser.add_argument('--min_views', type=int, default=2, help='training views that must agree (default 2)')
  parser.add_argument('--picture', help='also a PNG of the cloud from two sides')
  parser.add_argument('--scores', help='generated object scene: a JSON of the cloud against its exact surfaces')
  args = parser.parse_args(argv)
  if args.max_points < 1 or args.path_views < 0 or args.min_views < 1:
    raise ValueError(f'--max_points {args.max_points}, --path_views {args.path_views}, --min_views '
                     f'{args.min_views}: expected >= 1, >= 0, >= 1')
  if not (0. < args.min_opacity <= 1. and args.tolerance > 0.):
    raise ValueError(f'--min_opacity {args.min_opacity}, --tolerance {args.tolerance}: expected in (0, 1] and > 0')
  return args


def check_memory(n_train: int, train_pixels: int, view_pixels: int, max_points: int) -> None:
  """ValueError naming --max_points when the views and the kept points do not fit in the host's memory."""
  available = out_of_memory.host_available_bytes()
  needed = points_lib.host_bytes(n_train, train_pixels, view_pixels, max_points)
  if available is None or needed <= available:
    return
  largest = out_of_memory.largest_fitting(lambda n: points_lib.host_bytes(n_train, train_pixels, view_pixels, n),
                                          available)
  fits = f'the largest --max_points that fits is {largest}' if largest else (
      f'no --max_points fits: the {n_train} training views of {train_pixels} pixels alone do not')
  raise ValueError(f'--max_points {max_points} with {n_train} training views needs '
                   f'{out_of_memory.size_text(needed)} of host memory, {out_of_memory.size_text(available)} is '
                   f'available: {fits}')


def check_writable(flag: str, path: str, is_folder: bool = False) -> None:
  """ValueError naming flag when the file (or folder) path cannot be written (a read-only folder, a file where a
  folder should be): a file is made and deleted in the nearest existing folder that would hold it, before minutes
  of rendering; a full disk is left to show as one."""
  folder = os.path.abspath(path if is_folder else os.path.dirname(os.path.abspath(path)))
  while not os.path.exists(folder):
    folder = os.path.dirname(folder)
  try:
    with tempfile.TemporaryFile(dir=folder):
      pass
  except OSError as err:
    if err.errno == errno.ENOSPC:
      raise
    raise ValueError(f'{flag} {path!r} cannot be written: {err.strerror} ({folder!r}); choose a folder you can '
                     'write to') from None


def check_outputs(config, args) -> None:
  """ValueError naming the flag when --out, --colmap, --picture or --scores cannot be written; FileExistsError
  when one would replace something (unless Config.overwrite)."""
  for flag, path in (('--out', args.out), ('--colmap', args.colmap), ('--picture', args.picture),
                     ('--scores', args.scores)):
    if path:
      check_writable(flag, path, is_folder=flag == '--colmap')
  if config.overwrite:
    return
  for flag, path in (('--out', args.out), ('--scores', args.scores), ('--picture', args.picture)):
    if path and os.path.exists(path):
      raise FileExistsError(f'{flag} {path!r} exists; set Config.overwrite = True to replace it, or choose another')
  if args.colmap and os.path.isdir(args.colmap) and os.listdir(args.colmap):
    raise FileExistsError(f'--colmap {args.colmap!r} holds files; choose a new or empty folder, or set '
                          'Config.overwrite = True')


def render_view(render_fn, rays, chunk: int, ndc: bool, camtoworld=None, pixtocam=None, name=None):
  """points_lib.View of one view's rays [H,W,...]; a training view's camera as OpenCV axes and its K shifted to
  COLMAP's pixel centres (the offset its rays were made with, read at the image centre)."""
  out = inference.render_image(render_fn, rays, chunk)
  normals = None
  if 'normals' in out:
    normals = out['normals'] / np.maximum(np.linalg.norm(out['normals'], axis=-1, keepdims=True), 1e-12)
  view = points_lib.View(points=None, rgb=out['rgb'], acc=out['acc'], normals=normals, name=name)
  if camtoworld is None:
    view.points = rays.origins + out['distance_mean'][..., None] * rays.directions
    return view
  height, width = out['acc'].shape
  centre = rays.viewdirs[height // 2, width // 2].astype(np.float64)
  view.camtoworld = points_lib.opencv_camtoworld(camtoworld, centre)
  view.intrinsics = np.linalg.inv(np.asarray(pixtocam, np.float64))
  view.points = points_lib.world_points(rays, out['distance_mean'], view.camtoworld, ndc)
  pixel, _ = points_lib.project(view, view.camtoworld[:, 3] + centre[None])
  view.intrinsics[:2, 2] += np.array([width // 2 + .5, height // 2 + .5]) - pixel[0]
  return view


def write_colmap(folder: str, model: colmap_model.Model, image_paths, text: bool) -> None:
  """The model in folder/sparse/0 and copies of the image files in folder/images."""
  os.makedirs(os.path.join(folder, 'images'), exist_ok=True)
  for path in image_paths:
    shutil.copyfile(path, os.path.join(folder, 'images', os.path.basename(path)))
  (colmap_model.write_text if text else colmap_model.write_binary)(model, os.path.join(folder, 'sparse', '0'))


def save_picture(path: str, found: dict, views=((20, -100), (20, 20))) -> None:
  """A PNG of the cloud from each (elevation, azimuth), orthographic, far points first, each a dot of a size that
  fills the picture about once."""
  fig = matplotlib.figure.Figure(figsize=(6 * len(views), 4))
  for i, angles in enumerate(views):
    right, up, forward = mesh_tool.camera_axes(*angles)
    order = np.argsort(-(found['points'] @ forward))
    ax = fig.add_subplot(1, len(views), i + 1)
    ax.scatter(found['points'][order] @ right, found['points'][order] @ up, c=found['colours'][order],
               s=min(max(6e4 / len(order), .5), 20.), linewidths=0)
    ax.set_aspect('equal')
    ax.set_axis_off()
  fig.tight_layout()
  fig.savefig(path, dpi=100, bbox_inches='tight')


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  argv = sys.argv[1:] if argv is None else list(argv)
  args = parse_args(argv)
  config = cli.config_from_flags(args)
  ndc = bool(loader.ndc(config))
  if args.path_views and ndc:
    raise ValueError(f'--path_views {args.path_views}: the render path of an NDC scene ({config.dataset_loader!r}) '
                     'gives no world cameras to turn its depths into points; leave --path_views out')
  if args.scores:
    mesh_tool.check_scores_flag(config, args.scores)
  check_outputs(config, args)
  run_dir = run_dir_lib.check_run_dir(config)
  train = datasets.load_dataset('train', config)
  path = loader.render_path_rays(config) if args.path_views else None
  pixels = train.height * train.width
  check_memory(len(train.ids), pixels, max(pixels, 0 if path is None else int(np.prod(path.origins.shape[1:3]))),
               args.max_points)
  model, state = checkpoints.restore_model(config, run_dir, jax.tree.map(lambda x: x[0, 0, :8], train.rays))
  render_fn = inference.make_render_fn(config, model, state.params, int(state.step), compute_normals=not ndc)
  start = time.perf_counter()
  views = [render_view(render_fn, jax.tree.map(lambda x, i=i: x[i], train.rays), config.render_chunk_size, ndc,
                       train.camtoworlds[i], train.pixtocams[i], os.path.basename(train.image_paths[i]))
           for i in range(len(train.ids))]
  frames = np.linspace(0, len(path.origins) - 1, args.path_views).round().astype(int) if args.path_views else []
  others = [render_view(render_fn, jax.tree.map(lambda x, f=f: x[f], path), config.render_chunk_size, ndc)
            for f in frames]
  with out_of_memory.naming_host_setting('gathering the points', '--max_points'):
    found = points_lib.cloud(views, others, args.min_opacity, args.tolerance, args.min_views, args.max_points,
                             np.random.default_rng(0))
  seconds = round(time.perf_counter() - start, 1)
  if not len(found['points']):
    raise ValueError(f'no pixel of the {len(views) + len(others)} views is {args.min_opacity} opaque with '
                     f'{args.min_views} training views agreeing within {args.tolerance:.0%}: no point to write '
                     '(--min_opacity, --tolerance and --min_views set the rule)')
  for path in filter(None, (args.out, args.picture, args.scores)):
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  ply.write_points(args.out, found['points'], found['colours'], found['normals'])
  print(f'{len(found["points"])} points of step {int(state.step)} from {len(views)} training and {len(others)} path '
        f'views in {args.out!r}')
  if args.colmap:
    sizes = [image_io.image_size(p) for p in train.image_paths]
    write_colmap(args.colmap, points_lib.colmap_of(views, sizes, found), train.image_paths, args.colmap_text)
    print(f'COLMAP model and {len(views)} images in {args.colmap!r}')
  if args.picture:
    save_picture(args.picture, found)
  if args.scores:
    solids = scene_generator.read_scene(config.data_dir)['solids']
    record = {'run': config.checkpoint_dir, 'step': int(state.step), 'points': len(found['points']),
              'seconds': seconds, 'settings': {k: getattr(args, k) for k in (
                  'max_points', 'path_views', 'min_opacity', 'tolerance', 'min_views')},
              'scores': mesh_scores.score(found['points'], solids),
              'provenance': provenance.record(['python', '-m', 'tools.points', *argv])}
    atomic.write_text(args.scores, json.dumps(record, indent=1) + '\n')
    print(f'Chamfer distance {record["scores"]["chamfer"]:.3f} in {args.scores!r}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
