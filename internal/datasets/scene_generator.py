"""A generated scene with exact geometry: textured solids on a ground plane, ray-cast into a standard layout.

rig 'object': 24 train + 8 test cameras on a sphere of radius 4 around the objects, written in the Blender layout
(transforms_{train,test}.json, RGBA PNGs, transparent background). rig 'forward': 20 forward-facing cameras in
front of a floor, the objects and a back wall, written in the LLFF layout (poses_bounds.npy + images/).
Per view, depth/<image>.npy holds the exact z-depth of the pixel-centre ray (the loaders' ray parameter t, since
camera-frame |z| of every direction is 1; 0 where the ray hits nothing) and mask/<image>.png the fraction of
sub-pixel samples that hit an object (not the ground or wall). scene.json records the parameters and the solids.
"""

import json
import os
import shutil
import tempfile

import numpy as np

from internal.cameras import algebra, caster
from internal.cameras.records import Cameras
from internal.datasets import base, image_io

SCENE_VERSION = 3  # 3: two-tone solids and large ground checkers, which a small model fits in a CPU demo.
RIGS = ('object', 'forward')
N_TRAIN_OBJECT, N_TEST_OBJECT, N_FORWARD = 24, 8, 20
FOV_X = {'object': .85, 'forward': 1.}
AMBIENT = .35
EPS = 1e-9


def rotation(axis, angle: float) -> np.ndarray:
  """[3,3] rotation by angle about the unit vector axis [3]."""
  k = np.asarray(axis, np.float64)
  cross = np.array([[0., -k[2], k[1]], [k[2], 0., -k[0]], [-k[1], k[0], 0.]])
  return np.eye(3) * np.cos(angle) + np.sin(angle) * cross + (1. - np.cos(angle)) * np.outer(k, k)


def colours(rng: np.random.Generator, n: int) -> list:
  """n random RGB albedos (lists) in [0.15, 0.95]."""
  return rng.uniform(.15, .95, (n, 3)).round(4).tolist()


def sphere(centre, radius: float, rng: np.random.Generator) -> dict:
  """A sphere in two colours, alternating by quadrant of longitude and hemisphere (kind 'object')."""
  return {'shape': 'sphere', 'kind': 'object', 'centre': list(map(float, centre)), 'radius': float(radius),
          'colours': colours(rng, 2), 'freq': 1}


def box(centre, half, up, angle: float, rng: np.random.Generator) -> dict:
  """A box rotated by angle about the up axis, its faces checkered in cells of 0.5 (kind 'object')."""
  return {'shape': 'box', 'kind': 'object', 'centre': list(map(float, centre)), 'half': list(map(float, half)),
          'rotation': rotation(up, angle).tolist(), 'colours': colours(rng, 2), 'cell': .5}


def plane(kind: str, normal, offset: float, axes, radius, cell: float, rng: np.random.Generator) -> dict:
  """A checkered plane n.p = offset (a disc of the given radius, or infinite when radius is None)."""
  return {'shape': 'plane', 'kind': kind, 'normal': list(map(float, normal)), 'offset': float(offset),
          'axes': np.asarray(axes, float).tolist(), 'radius': radius, 'colours': colours(rng, 2), 'cell': cell}


def ring_point(angle: float, dist: float, z: float) -> tuple:
  """(x, y, z) at polar angle and distance dist from the z axis."""
  return dist * np.cos(angle), dist * np.sin(angle), z


def object_solids(rng: np.random.Generator) -> list:
  """Ground disc (z = 0, radius 1.5), two spheres and a box standing on it, 120 degrees apart (z up)."""
  angle = rng.uniform(0., 2. * np.pi)
  r_big, r_small = rng.uniform(.35, .5), rng.uniform(.2, .3)
  half = rng.uniform(.15, .28, 3)
  third = 2. * np.pi / 3.
  return [plane('ground', (0, 0, 1), 0., ((1, 0, 0), (0, 1, 0)), 1.5, .75, rng),
          sphere(ring_point(angle, .65, r_big), r_big, rng),
          box(ring_point(angle + third, .7, half[2]), half, (0., 0., 1.), rng.uniform(0., np.pi), rng),
          sphere(ring_point(angle + 2. * third, .7, r_small), r_small, rng)]


def forward_solids(rng: np.random.Generator) -> list:
  """Floor (y = -1), back wall (z = -6.5) and three solids on the floor (y up, cameras look down -z)."""
  r_big, r_small = rng.uniform(.5, .7), rng.uniform(.35, .5)
  half = rng.uniform(.35, .55, 3)
  return [plane('ground', (0, 1, 0), -1., ((1, 0, 0), (0, 0, 1)), None, .5, rng),
          plane('backdrop', (0, 0, 1), -6.5, ((1, 0, 0), (0, 1, 0)), None, .8, rng),
          sphere((rng.uniform(-.3, .3), -1. + r_big, rng.uniform(-3.2, -2.6)), r_big, rng),
          box((rng.uniform(-1.4, -1.0), -1. + half[1], rng.uniform(-4.4, -3.8)), half, (0., 1., 0.),
              rng.uniform(0., np.pi), rng),
          sphere((rng.uniform(1.0, 1.3), -1. + r_small, rng.uniform(-5., -4.4)), r_small, rng)]


def object_cameras(rng: np.random.Generator) -> tuple:
  """(train [24,3,4], test [8,3,4]) OpenGL cameras at radius 4 facing (0,0,.2); any train prefix is spread."""
  offset = rng.uniform(0., 2. * np.pi)
  k = np.arange(N_TRAIN_OBJECT)
  train = (offset + k * np.pi * (3. - np.sqrt(5.)), np.radians(15. + 45. * ((k * .6180339887) % 1.)))
  test = (offset + (np.arange(N_TEST_OBJECT) + .5) * 2. * np.pi / N_TEST_OBJECT, np.full(N_TEST_OBJECT, .56))
  target, up = np.array([0., 0., .2]), np.array([0., 0., 1.])

  def poses(azimuth, elevation):
    pos = 4. * np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                         np.sin(elevation)], -1)
    return np.stack([algebra.viewmatrix(p - target, up, p) for p in pos])
  return poses(*train), poses(*test)


def forward_cameras(rng: np.random.Generator) -> np.ndarray:
  """[20,3,4] OpenGL cameras on a 5x4 serpentine grid near z = 0, all facing a point at z = -4."""
  xs, ys = np.linspace(-.6, .6, 5), np.linspace(.3, -.3, 4)
  grid = [(x, y) for j, y in enumerate(ys) for x in (xs if j % 2 == 0 else xs[::-1])]
  target = np.array([0., -.5, -4.]) + rng.normal(0., .05, 3)
  jitter = rng.normal(0., .03, (N_FORWARD, 3))
  return np.stack([algebra.viewmatrix(p - target, np.array([0., 1., 0.]), p)
                   for p in np.array([(x, y, 0.) for x, y in grid]) + jitter])


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
  """Row-wise dot product of [R,3] arrays -> [R]."""
  return np.einsum('ij,ij->i', a, b)


def hit_sphere(solid: dict, o: np.ndarray, d: np.ndarray) -> np.ndarray:
  """[R] ray parameter of the first hit of rays (o, d) [R,3] with a sphere (inf: miss)."""
  oc = o - np.array(solid['centre'])
  a, b = dot(d, d), dot(oc, d)
  disc = b * b - a * (dot(oc, oc) - solid['radius'] ** 2)
  t = (-b - np.sqrt(np.maximum(disc, 0.))) / a
  return np.where((disc >= 0.) & (t > EPS), t, np.inf)


def hit_box(solid: dict, o: np.ndarray, d: np.ndarray) -> np.ndarray:
  """[R] first hit with an oriented box (slab test in its frame; inf: miss)."""
  rot, half = np.array(solid['rotation']), np.array(solid['half'])
  o_l, d_l = caster.mat_vec(rot.T, o - np.array(solid['centre'])), caster.mat_vec(rot.T, d)
  inv_d = 1. / np.where(d_l == 0., 1e-300, d_l)
  t1, t2 = (-half - o_l) * inv_d, (half - o_l) * inv_d
  t_min, t_max = np.minimum(t1, t2), np.maximum(t1, t2)
  t_near = np.maximum(np.maximum(t_min[:, 0], t_min[:, 1]), t_min[:, 2])
  t_far = np.minimum(np.minimum(t_max[:, 0], t_max[:, 1]), t_max[:, 2])
  return np.where((t_far >= t_near) & (t_near > EPS), t_near, np.inf)


def hit_plane(solid: dict, o: np.ndarray, d: np.ndarray) -> np.ndarray:
  """[R] hit with a plane, or a disc about the point offset*normal when radius is set (inf: miss)."""
  normal = np.array(solid['normal'])
  with np.errstate(divide='ignore', invalid='ignore'):
    t = (solid['offset'] - o @ normal) / (d @ normal)
  ok = np.isfinite(t) & (t > EPS)
  if solid['radius'] is not None:
    p = o + np.where(ok, t, 0.)[:, None] * d - solid['offset'] * normal
    ok &= dot(p, p) <= solid['radius'] ** 2
  return np.where(ok, t, np.inf)


def normal_at(solid: dict, p: np.ndarray) -> np.ndarray:
  """[R,3] outward unit normals at surface points p [R,3]."""
  if solid['shape'] == 'sphere':
    return (p - np.array(solid['centre'])) / solid['radius']
  if solid['shape'] == 'plane':
    return np.broadcast_to(np.array(solid['normal']), p.shape)
  rot, half = np.array(solid['rotation']), np.array(solid['half'])
  p_l = caster.mat_vec(rot.T, p - np.array(solid['centre']))
  axis = np.abs(p_l / half).argmax(-1)
  n_l = np.eye(3)[axis] * np.sign(np.take_along_axis(p_l, axis[:, None], -1))
  return caster.mat_vec(rot, n_l)


def pattern(solid: dict, p: np.ndarray) -> np.ndarray:
  """[R] bool texture of surface points p [R,3]: stripes (sphere) or checkers (box faces, planes)."""
  if solid['shape'] == 'sphere':
    q = (p - np.array(solid['centre'])) / solid['radius']
    u, v = np.arctan2(q[:, 1], q[:, 0]), np.arcsin(np.clip(q[:, 2], -1., 1.))
    return np.sin(solid['freq'] * u) * np.sin(solid['freq'] * v) > 0.
  if solid['shape'] == 'plane':
    coords = caster.mat_vec(np.array(solid['axes']), p)
  else:
    p_l = caster.mat_vec(np.array(solid['rotation']).T, p - np.array(solid['centre']))
    in_face = np.abs(p_l / np.array(solid['half'])).argmax(-1)[:, None] != np.arange(3)
    coords = np.where(in_face, p_l, 0.)
  return np.floor(coords / solid['cell'] + .5).sum(-1).astype(np.int64) % 2 == 1


def shade(solid: dict, p: np.ndarray, light: np.ndarray) -> np.ndarray:
  """[R,3] colour: textured albedo x (ambient + diffuse n.l), a view-independent radiance."""
  albedo = np.where(pattern(solid, p)[:, None], np.array(solid['colours'][0]), np.array(solid['colours'][1]))
  lambert = np.maximum(normal_at(solid, p) @ light, 0.)
  return albedo * (AMBIENT + (1. - AMBIENT) * lambert)[:, None]


HIT_FNS = {'sphere': hit_sphere, 'box': hit_box, 'plane': hit_plane}


def solid_bounds(solid: dict) -> np.ndarray:
  """[2, 3] axis-aligned box around a sphere, box or disc (ValueError for an infinite plane)."""
  centre = np.array(solid['centre']) if 'centre' in solid else np.array(solid['normal']) * solid['offset']
  if solid['shape'] == 'sphere':
    extent = np.full(3, solid['radius'])
  elif solid['shape'] == 'box':
    extent = np.abs(np.array(solid['rotation'])) @ np.array(solid['half'])
  elif solid['radius'] is not None:
    extent = np.abs(np.array(solid['axes'])).T @ np.full(2, solid['radius'])
  else:
    raise ValueError(f'the {solid["kind"]} plane of the generated scene is unbounded')
  return np.stack([centre - extent, centre + extent])


def scene_bounds(scene: dict) -> np.ndarray:
  """[2, 3] axis-aligned box around every solid of a scene with finite solids (the object rig)."""
  boxes = np.stack([solid_bounds(solid) for solid in scene['solids']])
  return np.stack([boxes[:, 0].min(0), boxes[:, 1].max(0)])


def trace(scene: dict, o: np.ndarray, d: np.ndarray) -> tuple:
  """Rays [R,3] -> (colour [R,3], t [R] of the nearest hit (inf: none), hit-an-object [R] bool)."""
  solids, light = scene['solids'], np.array(scene['light'])
  ts = np.stack([HIT_FNS[s['shape']](s, o, d) for s in solids])
  nearest, t = ts.argmin(0), ts.min(0)
  colour = np.zeros(o.shape)
  for i, solid in enumerate(solids):
    sel = (nearest == i) & np.isfinite(t)
    colour[sel] = shade(solid, o[sel] + t[sel, None] * d[sel], light)
  is_object = np.array([s['kind'] == 'object' for s in solids])[nearest] & np.isfinite(t)
  return colour, t, is_object


def render_view(scene: dict, c2w: np.ndarray, pixtocam: np.ndarray, height: int, width: int) -> dict:
  """One view: rgb [H,W,3] (mean over hits), alpha, object coverage [H,W] (spp^2 samples), depth [H,W]."""
  spp = scene['spp']
  offsets = [((i + .5) / spp, (j + .5) / spp) for j in range(spp) for i in range(spp)] + [(.5, .5)]
  camera, pixels = Cameras(c2w[None], pixtocam[None]), caster.image_pixels(0, height, width)
  dirs = np.stack([caster.world_directions(camera, pixels, caster.camera_directions(camera, pixels, True, offset))
                   for offset in offsets]).reshape(-1, 3)
  colour, t, is_object = trace(scene, np.broadcast_to(c2w[:3, 3], dirs.shape), dirs)
  colour, t, is_object = [x.reshape((len(offsets), height, width) + x.shape[1:]) for x in (colour, t, is_object)]
  hit = np.isfinite(t[:-1])
  return {'rgb': colour[:-1].sum(0) / np.maximum(hit.sum(0), 1)[..., None], 'alpha': hit.mean(0),
          'object_mask': is_object[:-1].mean(0), 'depth': np.where(np.isfinite(t[-1]), t[-1], 0.).astype(np.float32)}


def scene_params(rig: str, seed: int, height: int, width: int, spp: int) -> dict:
  """The parameters that identify a generated scene (what scene.json must match)."""
  base.check_choice('Config.generated_rig', rig, RIGS)
  return {'version': SCENE_VERSION, 'rig': rig, 'seed': int(seed), 'height': int(height), 'width': int(width),
          'spp': int(spp)}


def build_scene(params: dict) -> tuple:
  """(scene dict with solids, light and fov; {split or 'all': cameras [N,3,4]}) from the parameters."""
  rng = np.random.default_rng([SCENE_VERSION, params['seed']])
  if params['rig'] == 'object':
    solids, light = object_solids(rng), algebra.normalize(np.array([.5, .3, 1.]))
    train, test = object_cameras(rng)
    views = {'train': train, 'test': test}
  else:
    solids, light = forward_solids(rng), algebra.normalize(np.array([.3, 1., .6]))
    views = {'all': forward_cameras(rng)}
  scene = dict(params, solids=solids, light=light.tolist(), camera_angle_x=FOV_X[params['rig']])
  return scene, views


def write_ground_truth(out_dir: str, stem: str, view: dict) -> None:
  """Writes depth/<stem>.npy (f32 [H,W]) and mask/<stem>.png (object coverage)."""
  for folder in ('depth', 'mask'):
    os.makedirs(os.path.dirname(os.path.join(out_dir, folder, stem)), exist_ok=True)
  np.save(os.path.join(out_dir, 'depth', stem + '.npy'), view['depth'])
  image_io.write_png(os.path.join(out_dir, 'mask', stem + '.png'), view['object_mask'][..., None])


def write_object_rig(out_dir: str, scene: dict, views: dict) -> None:
  """Blender layout: transforms_{split}.json, {split}/r_i.png (RGBA) plus depth and masks."""
  h, w = scene['height'], scene['width']
  pixtocam = algebra.focal_pixtocam(.5 * w / np.tan(.5 * scene['camera_angle_x']), h, w)
  for split, poses in views.items():
    os.makedirs(os.path.join(out_dir, split), exist_ok=True)
    frames = []
    for i, pose in enumerate(poses):
      view = render_view(scene, pose, pixtocam, h, w)
      image_io.write_png(os.path.join(out_dir, split, f'r_{i}.png'),
                         np.concatenate([view['rgb'], view['alpha'][..., None]], -1))
      write_ground_truth(out_dir, f'{split}/r_{i}', view)
      frames.append({'file_path': f'./{split}/r_{i}', 'transform_matrix': algebra.to_homogeneous(pose).tolist()})
    with open(os.path.join(out_dir, f'transforms_{split}.json'), 'w') as f:
      json.dump({'camera_angle_x': scene['camera_angle_x'], 'frames': frames}, f, indent=1)


def write_forward_rig(out_dir: str, scene: dict, views: dict) -> None:
  """LLFF layout: poses_bounds.npy ([down, right, back, t, hwf] + depth bounds) and images/imageNNN.png."""
  h, w = scene['height'], scene['width']
  focal = .5 * w / np.tan(.5 * scene['camera_angle_x'])
  pixtocam = algebra.focal_pixtocam(focal, h, w)
  os.makedirs(os.path.join(out_dir, 'images'), exist_ok=True)
  rows = []
  for i, pose in enumerate(views['all']):
    view = render_view(scene, pose, pixtocam, h, w)
    image_io.write_png(os.path.join(out_dir, 'images', f'image{i:03d}.png'), view['rgb'])
    write_ground_truth(out_dir, f'images/image{i:03d}', view)
    llff_pose = np.stack([-pose[:, 1], pose[:, 0], pose[:, 2], pose[:, 3], [h, w, focal]], 1)
    rows.append(np.concatenate([llff_pose.ravel(), [.9 * view['depth'].min(), 1.1 * view['depth'].max()]]))
  np.save(os.path.join(out_dir, 'poses_bounds.npy'), np.array(rows))


def write_scene(out_dir: str, rig: str = 'object', seed: int = 0, height: int = 64, width: int = 80,
                spp: int = 2) -> dict:
  """Renders the scene into out_dir (created) in the rig's standard layout; returns the scene dict."""
  scene, views = build_scene(scene_params(rig, seed, height, width, spp))
  os.makedirs(out_dir, exist_ok=True)
  (write_object_rig if rig == 'object' else write_forward_rig)(out_dir, scene, views)
  with open(os.path.join(out_dir, 'scene.json'), 'w') as f:
    json.dump(scene, f, indent=1)
  return scene


def read_scene(scene_dir: str) -> dict:
  """The scene.json of a generated scene folder."""
  path = base.require_file(os.path.join(scene_dir, 'scene.json'), 'generated scene description')
  try:
    with open(path) as f:
      return json.load(f)
  except (OSError, ValueError) as err:
    raise base.DatasetError(f'cannot read {path!r} (expected the JSON written by write_scene): {err}') from err


def check_same(scene_dir: str, params: dict) -> None:
  """Raises unless scene_dir holds a generated scene with exactly these parameters."""
  if not os.path.isfile(os.path.join(scene_dir, 'scene.json')):
    raise base.DatasetError(f'Config.data_dir = {scene_dir!r} exists but holds no generated scene (no scene.json; '
                            f'found {base.listing(scene_dir)[:10]}); choose an empty or new folder')
  stored = {k: read_scene(scene_dir).get(k) for k in params}
  if stored != params:
    raise base.DatasetError(f'Config.data_dir = {scene_dir!r} holds a different generated scene {stored}; the config '
                            f'asks for {params}. Use another Config.data_dir or delete that folder.')


def ensure_scene(scene_dir: str, rig: str, seed: int, size, spp: int = 2) -> None:
  """Writes the scene into scene_dir if it is absent or empty; otherwise checks that it is the same scene."""
  params = scene_params(rig, seed, size[0], size[1], spp)
  if os.path.exists(scene_dir):
    base.require_data_folder(scene_dir, 'a generated scene (or a new path to write one to)')
  if base.listing(scene_dir):
    check_same(scene_dir, params)
    return
  parent = os.path.dirname(os.path.abspath(scene_dir))
  os.makedirs(parent, exist_ok=True)
  tmp = tempfile.mkdtemp(prefix='.generating-', dir=parent)
  try:
    os.chmod(tmp, 0o755)
    write_scene(tmp, rig, seed, size[0], size[1], spp)
    os.replace(tmp, scene_dir)
  except OSError:
    if not os.path.isfile(os.path.join(scene_dir, 'scene.json')):
      raise
  finally:
    shutil.rmtree(tmp, ignore_errors=True)
  check_same(scene_dir, params)


def ground_truth_stems(rig: str, split: str, ids) -> list:
  """Relative stems (under depth/ and mask/) of the views ids of a split."""
  if rig == 'object':
    return [f'{split}/r_{i}' for i in ids]
  return [f'images/image{i:03d}' for i in ids]


def load_ground_truth(scene_dir: str, rig: str, split: str, ids, factor: int, mode: str) -> tuple:
  """(depths [N,H,W], object masks [N,H,W]) f32 at the loaded resolution (exact for factor 1)."""
  stems = ground_truth_stems(rig, split, ids)
  depths, masks = [], []
  for stem in stems:
    path = base.require_file(os.path.join(scene_dir, 'depth', stem + '.npy'), 'generated scene depth')
    depths.append(image_io.downsample(np.load(path)[..., None], factor, mode)[..., 0])
    masks.append(image_io.downsample(image_io.read_image(os.path.join(scene_dir, 'mask', stem + '.png'), 'L'),
                                     factor, mode)[..., 0])
  return np.stack(depths), np.stack(masks)
