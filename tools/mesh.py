"""Extracts a mesh of a trained run's density field: a PLY of the surface {density = level} with vertex colours.

  python -m tools.mesh --gin_configs=configs/demo.gin --resolution 256 [--level 5] [--bounds X0 Y0 Z0 X1 Y1 Z1]

Pass the gin configs and bindings used for training. The density is evaluated on a resolution^3 grid inside the
scene's bounds (the generated object scene: the box around its solids, 5% margin; Blender: the cube [-1.5, 1.5]^3
that holds its objects; NDC scenes (LLFF, the generated forward scene): the NDC box, and the mesh is in NDC
coordinates; DTU: the region its test views' object masks bound, see mask_region; packed scenes: --bounds,
in the run's world coordinates), z-slab by z-slab so that memory stays
bounded (512^3 included), then marching cubes at --level (default: the density that makes one interval of the
run's own samples half opaque, ln 2 x samples / (far - near), so it follows the scene's scale). Vertex colours
are the radiance at each vertex seen head-on from outside (view direction = -normal; in NDC scenes the normal is
an NDC one while the model was trained on world directions, an approximation). Writes
<run>/mesh_step_<step>_<resolution>.ply (or --out) and never replaces a file unless Config.overwrite = True. A
field that never reaches the level is an error, and no file is written.
"""
import os
import sys

import jax
import matplotlib.collections
import matplotlib.figure
import numpy as np

from internal import cli
from internal import datasets
from internal.datasets import loader
from internal.datasets import generated_scene
from internal.evaluation import mesh
from internal.evaluation import ply
from internal.run import checkpoints
from internal.run import run_dir as run_dir_lib

BLENDER_BOX = ((-1.5, -1.5, -1.5), (1.5, 1.5, 1.5))  # Holds every object of the Blender scenes.
NDC_BOX = ((-1., -1., -1.), (1., 1., .99))  # NDC z = 1 is infinitely far.
MARGIN = .05  # Of the generated scene's box, on each side.


def scene_bounds(config, flag_bounds) -> np.ndarray:
  """[2, 3] region to mesh: --bounds, else the scene's own (see the module docstring); ValueError otherwise."""
  if flag_bounds:
    bounds = np.array(flag_bounds, np.float64).reshape(2, 3)
    if not np.all(bounds[1] > bounds[0]):
      raise ValueError(f'--bounds {flag_bounds}: expected X0 Y0 Z0 X1 Y1 Z1 with X1 > X0, Y1 > Y0, Z1 > Z0')
    return bounds
  if loader.ndc(config):
    return np.array(NDC_BOX)
  if config.dataset_loader == 'generated':
    box = generated_scene.scene_bounds(generated_scene.read_scene(config.data_dir))
    return box + np.array([-1., 1.])[:, None] * MARGIN * (box[1] - box[0])
  if config.dataset_loader == 'blender':
    return np.array(BLENDER_BOX)
  if config.dataset_loader == 'dtu':
    return mask_region(datasets.load_dataset('test', config))
  raise ValueError(f'Config.dataset_loader = {config.dataset_loader!r} has no default region to mesh; give it with '
                   '--bounds X0 Y0 Z0 X1 Y1 Z1 (world coordinates of the run)')


def mask_region(test_set) -> np.ndarray:
  """[2, 3] the object-mask region of DTU's test views: the intersection over the views of the box around each
  view's mask rays from near to far (a loose box around the visual hull; it holds the object)."""
  boxes = []
  for view in range(len(test_set.ids)):
    inside = test_set.masks[view, ..., 0] > .5
    if inside.any():
      rays = [getattr(test_set.rays, name)[view][inside] for name in ('origins', 'directions', 'near', 'far')]
      ends = np.concatenate([rays[0] + rays[1] * rays[2], rays[0] + rays[1] * rays[3]])
      boxes.append([ends.min(0), ends.max(0)])
  if not boxes:
    raise ValueError(f'the DTU test views {test_set.ids} have empty object masks: give the region with --bounds')
  boxes = np.array(boxes)
  return np.stack([boxes[:, 0].max(0), boxes[:, 1].min(0)])


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


def parse_args(argv):
  parser = cli.flag_parser(__doc__.split('\n')[0])
  parser.add_argument('--resolution', type=int, default=256, help='grid points along each axis (default 256)')
  parser.add_argument('--level', type=float, help='the density of the surface (default: ln 2 / the interval '
                                                  'between the last pass\'s samples, (far - near) / samples)')
  parser.add_argument('--bounds', type=float, nargs=6, metavar='V', help='X0 Y0 Z0 X1 Y1 Z1 of the region')
  parser.add_argument('--chunk', type=int, default=65536, help='grid points evaluated at once (default 65536)')
  parser.add_argument('--out', help='the PLY file (default <run>/mesh_step_<step>_<resolution>.ply)')
  parser.add_argument('--picture', help='also a PNG of the mesh (matplotlib, two views), e.g. for a README')
  args = parser.parse_args(argv)
  if args.resolution < 2 or args.chunk < 1:
    parser.error(f'--resolution {args.resolution} and --chunk {args.chunk}: expected >= 2 and >= 1')
  return args


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  args = parse_args(argv)
  config = cli.config_from_flags(args)
  run_dir = run_dir_lib.check_run_dir(config)
  bounds = scene_bounds(config, args.bounds)
  example = jax.tree.map(lambda x: x.reshape(-1, x.shape[-1])[:8], datasets.load_dataset('train', config).rays)
  model, state = checkpoints.restore_model(config, run_dir, example)
  step = int(state.step)
  out = args.out or os.path.join(run_dir, f'mesh_step_{step}_{args.resolution}.ply')
  if os.path.exists(out) and not config.overwrite:
    raise FileExistsError(f'{out!r} exists; set Config.overwrite = True to replace it, or choose --out')
  cell = float(np.max((bounds[1] - bounds[0]) / (args.resolution - 1)))
  density_fn, colour_fn = mesh.field_functions(config, model, state.params, step, cell)
  level = mesh.surface_level(config, model) if args.level is None else args.level
  verts, faces, normals = mesh.march(density_fn, bounds, args.resolution, level, args.chunk)
  colours = mesh.vertex_colours(colour_fn, verts, normals, args.chunk)
  ply.write(out, verts, faces, colours)
  if args.picture:
    save_picture(args.picture, verts, faces, colours, normals)
  print(f'{len(verts)} vertices, {len(faces)} triangles of step {step} at density {level:.3g} in {out!r}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
