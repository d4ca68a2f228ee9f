"""Extracts a mesh of a trained run's density field: a PLY of the surface {density = level} with vertex colours.

  python -m tools.mesh --gin_configs=configs/demo.gin --resolution 256 [--level 5] [--bounds X0 Y0 Z0 X1 Y1 Z1]

Pass the gin configs and bindings used for training. The density is evaluated on a resolution^3 grid inside the
scene's bounds (its loader's region, internal/datasets/loader.mesh_bounds: the generated object scene: the box
around its solids, 5% margin; Blender: the cube [-1.5, 1.5]^3 that holds its objects; NDC scenes (LLFF, the
generated forward scene, forward captures): the NDC box, and the mesh is in NDC coordinates; DTU: the region its
test views' object masks bound; inward captures: the box around the sparse points inside the cameras' orbit;
packed scenes: --bounds, in the run's world coordinates), z-slab by z-slab so that host memory grows with
resolution^2 (internal/geometry/mesh.py), then marching cubes at --level (default: the density that makes one
interval of the run's own samples half opaque, ln 2 x samples / (far - near), so it follows the scene's scale).
The memory --resolution needs on the host and --chunk on the device are checked before any work. Vertex colours
are the radiance at each vertex seen head-on from outside (view direction = -normal; in NDC scenes the normal is
an NDC one while the model was trained on world directions, an approximation). Writes
<run>/mesh_step_<step>_<resolution>.ply (or --out) and never replaces a file unless Config.overwrite = True. A
field that stays on one side of the level is an error naming its minimum and maximum, and no file is written.
On the generated object scene --scores FILE also writes the mesh's distances to the scene's exact surfaces, overall
and per solid (Chamfer distance and coverage, internal/geometry/mesh_scores.py), the mesh's size, the seconds
meshing took (the grid and the colours, once compiled) and provenance (command, commit, machine), e.g. into
results/mesh/ to be committed.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import json
import math
import os
import sys
import time

import jax
import matplotlib.collections
import matplotlib.figure
import numpy as np

from internal import atomic
from internal import cli
from internal import datasets
from internal.datasets import loader
from internal.geometry import mesh
from internal.geometry import mesh_scores
from internal.geometry import ply
from internal.run import checkpoints
from internal.run import out_of_memory
from internal.run import run_dir as run_dir_lib
from internal.datasets import scene_generator
from tools import provenance


def scene_bounds(config, flag_bounds) -> np.ndarray:
  """[2, 3] region to mesh: --bounds, else the scene's own (its loader's); ValueError when it has none."""
  if flag_bounds:
    bounds = np.array(flag_bounds, np.float64).reshape(2, 3)
    if not np.all(bounds[1] > bounds[0]):
      raise ValueError(f'--bounds {flag_bounds}: expected X0 Y0 Z0 X1 Y1 Z1 with X1 > X0, Y1 > Y0, Z1 > Z0')
    return bounds
  bounds = loader.mesh_bounds(config)
  if bounds is None:
    raise ValueError(f'the scene of Config.dataset_loader = {config.dataset_loader!r} gives no region of its own to '
                     'mesh; give it with --bounds X0 Y0 Z0 X1 Y1 Z1 (world coordinates of the run)')
  return bounds


def _too_big(flag: str, value: int, needed: int, available: int, where: str, largest: int) -> ValueError:
  """The one-line error of a flag whose work does not fit in memory, with the largest value that fits."""
  fits = f'the largest {flag} that fits is {largest}' if largest else f'no {flag} fits'
  return ValueError(f'{flag} {value} needs {out_of_memory.size_text(needed)} of {where} memory, '
                    f'{out_of_memory.size_text(available)} is available: {fits}')


def check_resolution(resolution: int) -> None:
  """ValueError naming --resolution when one slab of its grid does not fit in the host's available memory."""
  available = out_of_memory.host_available_bytes()
  if available is not None and mesh.host_bytes(resolution) > available:
    largest = out_of_memory.largest_fitting(lambda r: mesh.host_bytes(max(r, 2)), available)
    raise _too_big('--resolution', resolution, mesh.host_bytes(resolution), available, 'host',
                   largest if largest >= 2 else 0)


def field_functions(config, model, state, resolution: int, cell: float, chunk: int):
  """mesh.field_functions for the run's step, compiled for chunk points; ValueError naming --chunk when they do not
  fit in the device's available memory beside the slab on the host."""
  chunk = min(chunk, mesh.slab_points(resolution))  # More points than a slab holds would only be padding.
  compile_for = lambda n: mesh.field_functions(config, model, state.params, int(state.step), cell, n)
  density_fn, colour_fn, needed = compile_for(chunk)
  available = out_of_memory.device_available_bytes(jax.local_devices()[0], mesh.host_bytes(resolution))
  if available is not None and needed > available:
    at_one = compile_for(1)[2]  # XLA's memory grows linearly with the points, from what the parameters need.
    largest = out_of_memory.largest_fitting(lambda n: at_one + (needed - at_one) * (n - 1) // max(chunk - 1, 1),
                                            available)
    raise _too_big('--chunk', chunk, needed, available, 'device', largest)
  return density_fn, colour_fn, chunk


def camera_axes(elevation: float, azimuth: float):
  """(right, up, forward) unit vectors [3] of an orthographic camera looking at the origin from the given angles
  (degrees; z up)."""
  e, a = np.radians([elevation, azimuth])
  forward = -np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
  right = np.array([-np.sin(a), np.cos(a), 0.])
  return right, np.cross(right, forward), forward


def save_picture(path: str, verts, faces, colours, normals, views=((20, -100), (20, 20))) -> None:
  """A PNG of the mesh from each (elevation, azimuth): triangles facing the camera, far to near (painter's
  algorithm), in their vertices' mean colour shaded by how squarely they face it (0.5 + 0.5 cos)."""
  fig = matplotlib.figure.Figure(figsize=(6 * len(views), 4))
  face_normals = normals[faces].mean(1)
  face_normals /= np.maximum(np.linalg.norm(face_normals, axis=-1, keepdims=True), 1e-12)
  for i, angles in enumerate(views):
    right, up, forward = camera_axes(*angles)
    facing = -face_normals @ forward
    shown = np.flatnonzero(facing > 0)
    shown = shown[np.argsort(-(verts[faces[shown]].mean(1) @ forward))]  # Far first.
    flat = np.stack([verts @ right, verts @ up], -1)[faces[shown]]
    shade = (.5 + .5 * facing[shown])[:, None] * colours[faces[shown]].mean(1)
    ax = fig.add_subplot(1, len(views), i + 1)
    ax.add_collection(matplotlib.collections.PolyCollection(flat, facecolors=shade, edgecolors='face',
                                                            linewidths=.2))
    ax.autoscale_view()
    ax.set_aspect('equal')
    ax.set_axis_off()
  fig.tight_layout()
  fig.savefig(path, dpi=100)


def check_scores_flag(config, path: str) -> None:
  """ValueError naming --scores unless the scene is the generated object scene; FileExistsError for a file there."""
  if (config.dataset_loader, config.generated_rig) != ('generated', 'object'):
    raise ValueError(f'--scores {path}: only the generated object scene (Config.dataset_loader = \'generated\', '
                     "Config.generated_rig = 'object') has exact surfaces to score a mesh against; got "
                     f'{config.dataset_loader!r}' + (f' ({config.generated_rig!r} rig)' if config.dataset_loader
                                                     == 'generated' else ''))
  if os.path.exists(path) and not config.overwrite:
    raise FileExistsError(f'{path!r} exists; set Config.overwrite = True to replace it, or choose --scores')


def write_scores(path: str, config, surface: dict, argv) -> dict:
  """Writes the mesh's scores against the scene's exact surfaces, its size and provenance to path; the record."""
  solids = scene_generator.read_scene(config.data_dir)['solids']
  record = {'run': config.checkpoint_dir, 'step': surface['step'], 'resolution': surface['resolution'],
            'level': surface['level'], 'vertices': len(surface['verts']), 'triangles': len(surface['faces']),
            'seconds': surface['seconds'], 'scores': mesh_scores.score(surface['verts'], solids),
            'provenance': provenance.record(['python', '-m', 'tools.mesh', *argv])}
  atomic.write_text(path, json.dumps(record, indent=1) + '\n')
  return record


def parse_args(argv):
  parser = cli.flag_parser(__doc__.split('\n')[0])
  parser.add_argument('--resolution', type=int, default=256, help='grid points along each axis (default 256)')
  parser.add_argument('--level', type=float, help='the density of the surface (default: ln 2 / the interval '
                                                  'between the last pass\'s samples, (far - near) / samples)')
  parser.add_argument('--bounds', type=float, nargs=6, metavar='V', help='X0 Y0 Z0 X1 Y1 Z1 of the region')
  parser.add_argument('--chunk', type=int, default=65536, help='grid points evaluated at once (default 65536)')
  parser.add_argument('--out', help='the PLY file (default <run>/mesh_step_<step>_<resolution>.ply)')
  parser.add_argument('--picture', help='also a PNG of the mesh (matplotlib, two views), e.g. for a README')
  parser.add_argument('--scores', help='generated object scene: also a JSON of the mesh against its exact surfaces')
  args = parser.parse_args(argv)
  if args.resolution < 2 or args.chunk < 1:
    raise ValueError(f'--resolution {args.resolution} and --chunk {args.chunk}: expected >= 2 and >= 1')
  if args.level is not None and not (math.isfinite(args.level) and args.level > 0):
    raise ValueError(f'--level {args.level}: expected a positive finite density (the density is >= 0)')
  return args


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  argv = sys.argv[1:] if argv is None else list(argv)
  args = parse_args(argv)
  check_resolution(args.resolution)
  config = cli.config_from_flags(args)
  if args.scores:
    check_scores_flag(config, args.scores)
  run_dir = run_dir_lib.check_run_dir(config)
  bounds = scene_bounds(config, args.bounds)
  example = jax.tree.map(lambda x: x.reshape(-1, x.shape[-1])[:8], datasets.load_dataset('train', config).rays)
  model, state = checkpoints.restore_model(config, run_dir, example)
  step = int(state.step)
  out = args.out or os.path.join(run_dir, f'mesh_step_{step}_{args.resolution}.ply')
  if os.path.exists(out) and not config.overwrite:
    raise FileExistsError(f'{out!r} exists; set Config.overwrite = True to replace it, or choose --out')
  cell = float(np.max((bounds[1] - bounds[0]) / (args.resolution - 1)))
  density_fn, colour_fn, chunk = field_functions(config, model, state, args.resolution, cell, args.chunk)
  level = mesh.surface_level(config, model) if args.level is None else args.level
  start = time.perf_counter()
  with out_of_memory.naming_setting('meshing', '--chunk'), out_of_memory.naming_host_setting('meshing', '--resolution'):
    try:
      verts, faces, normals = mesh.march(density_fn, bounds, args.resolution, level, chunk)
    except mesh.EmptyFieldError as err:
      raise mesh.EmptyFieldError(f'{err} (--level sets the level, --bounds the region)') from err
    colours = mesh.vertex_colours(colour_fn, verts, normals, chunk)
  seconds = round(time.perf_counter() - start, 1)
  ply.write(out, verts, faces, colours)
  if args.picture:
    save_picture(args.picture, verts, faces, colours, normals)
  print(f'{len(verts)} vertices, {len(faces)} triangles of step {step} at density {level:.3g} in {out!r}')
  if args.scores:
    scores = write_scores(args.scores, config, {'step': step, 'resolution': args.resolution, 'level': level,
                                                'verts': verts, 'faces': faces, 'seconds': seconds}, argv)['scores']
    print(f'Chamfer distance {scores["chamfer"]:.3f}; per solid, its Chamfer distance and the coverage of its '
          'surface: ' + ', '.join(f'{name} {s["chamfer"] or float("nan"):.3f} and {s["coverage"]:.0%}'
                                  for name, s in scores['solids'].items()) + f'; in {args.scores!r}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
