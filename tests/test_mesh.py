"""Meshes (tools.mesh, geometry/mesh.py, geometry/ply.py): marching cubes slab by slab, the PLY file, the
empty field, and the mesh of a trained generated scene against its exact surfaces (Chamfer distance)."""

import json
import math
import os
import re
import tracemalloc
import types

import jax
import numpy as np
import pytest

from conftest import SHARED_DATA
from internal import cli
from internal import datasets
from internal.configs import Config
from internal.datasets import dtu
from internal.datasets import scene_generator
from internal.geometry import mesh
from internal.geometry import mesh_scores
from internal.geometry import ply
from internal.run import checkpoints
from internal.run import out_of_memory
from internal.pipeline import loop
from test_checkpoints import DEMO, ROOT, TINY, tiny_config
from tools import mesh as mesh_tool

RADIUS = .6


def _ball(points):
  """A density of 10 inside a ball of radius RADIUS at the origin and 0 outside, smooth over 0.1."""
  return 10. / (1. + np.exp((np.linalg.norm(points, axis=-1) - RADIUS) / .02))


@pytest.mark.parametrize('slab', [4, 64])
def test_the_ball_is_found_at_its_radius_with_outward_normals_whatever_the_slabs(slab, monkeypatch):
  monkeypatch.setattr(mesh, 'SLAB', slab)
  bounds = np.array([[-1., -1., -1.], [1., 1., 1.]])
  verts, faces, normals = mesh.march(_ball, bounds, 41, 5., chunk=1000)
  cell = 2. / 40
  assert np.abs(np.linalg.norm(verts, axis=-1) - RADIUS).max() < cell / 4  # The level 5 lies at the radius.
  assert np.min(np.sum(normals * verts, -1) / np.linalg.norm(verts, axis=-1)) > .9
  # Merged across slabs: one closed surface, every edge shared by exactly two triangles.
  edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
  _, counts = np.unique(edges, axis=0, return_counts=True)
  assert np.all(counts == 2)


@pytest.mark.parametrize('level, side', [(5., 'stays below'), (.1, 'stays above')])
def test_a_field_on_one_side_of_the_level_is_empty_and_the_side_is_named(level, side):
  bounds = np.array([[-1., -1., -1.], [1., 1., 1.]])
  field = lambda p: .3 + .2 * (p[:, 0] > 0)  # 0.3 on one half, 0.5 on the other.
  with pytest.raises(mesh.EmptyFieldError, match=rf'the density {side} the level {level:g} inside the bounds '
                                                 r'\(its minimum is 0.3, its maximum 0.5\)'):
    mesh.march(field, bounds, 9, level, chunk=100)


def test_the_host_memory_of_a_mesh_is_one_slab_at_host_bytes_per_point(monkeypatch):
  bounds = np.array([[-1., -1., -1.], [1., 1., 1.]])
  ball = lambda p: _ball(p).astype(np.float32)
  for resolution in (24, 96):  # The smaller grid in one slab; the larger in three.
    tracemalloc.start()
    mesh.march(ball, bounds, resolution, 5., chunk=8192)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # Measured here: 40 to 48 bytes a slab point at 64^3 to 256^3, the surface included.
    assert .6 * mesh.host_bytes(resolution) < peak <= mesh.host_bytes(resolution), (resolution, peak)


def test_ply_header_and_records_by_hand(tmp_path):
  verts = np.array([[0., 0., 0.], [1., 0., 0.], [0., 1., .5]], np.float32)
  faces = np.array([[0, 1, 2]])
  colours = np.array([[0., .5, 1.], [1., 1., 1.], [.2, 0., 0.]])
  path = tmp_path / 'm.ply'
  ply.write(str(path), verts, faces, colours)
  data = path.read_bytes()
  assert data.startswith(b'ply\nformat binary_little_endian 1.0\n')
  assert b'element vertex 3\n' in data and b'element face 1\n' in data
  body = data[data.index(b'end_header\n') + 11:]
  assert len(body) == 3 * (3 * 4 + 3) + (1 + 3 * 4)
  assert body[12:15] == bytes([0, 128, 255]) and body[-13:] == bytes([3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0])
  read_verts, read_faces, read_colours = ply.read(str(path))
  np.testing.assert_array_equal(read_verts, verts)
  np.testing.assert_array_equal(read_faces, faces)
  assert read_colours[2].tolist() == [51, 0, 0]


def test_bounds_per_scene_kind_and_a_clear_error_where_there_are_none():
  scene, _ = scene_generator.build_scene(scene_generator.scene_params('object', 0, 32, 40, 2))
  tops = []
  for solid in scene['solids'][1:]:
    if solid['shape'] == 'sphere':
      tops.append(solid['centre'][2] + solid['radius'])
    else:  # The highest of the box's 8 corners.
      corners = np.array(np.meshgrid(*[[-h, h] for h in solid['half']])).reshape(3, -1).T
      tops.append((np.array(solid['centre']) + corners @ np.array(solid['rotation']).T)[:, 2].max())
  np.testing.assert_allclose(scene_generator.scene_bounds(scene), [[-1.5, -1.5, 0.], [1.5, 1.5, max(tops)]], atol=1e-9)
  assert mesh_tool.scene_bounds(Config(dataset_loader='blender'), None).tolist() == [[-1.5] * 3, [1.5] * 3]
  assert mesh_tool.scene_bounds(Config(dataset_loader='llff'), None)[0].tolist() == [-1.] * 3
  with pytest.raises(ValueError, match="Config.dataset_loader = 'packed' .* --bounds"):
    mesh_tool.scene_bounds(Config(dataset_loader='packed'), None)
  with pytest.raises(ValueError, match='X1 > X0'):
    mesh_tool.scene_bounds(Config(dataset_loader='dtu'), [0, 0, 0, 1, -1, 1])
  assert mesh_tool.scene_bounds(Config(dataset_loader='packed'), [0, 0, 0, 1, 2, 3]).tolist() == [[0, 0, 0], [1, 2, 3]]


def _view(origin, direction, masked):
  """One view of 2 x 1 pixels, both rays from origin along direction; mask [2] which pixels hold the object."""
  shape = (1, 2, 1)
  return (np.broadcast_to(origin, shape[:2] + (3,)), np.broadcast_to(direction, shape[:2] + (3,)),
          np.broadcast_to(np.array(masked, float).reshape(shape), shape[:2] + (3,)))


def test_the_dtu_region_intersects_the_boxes_of_the_views_mask_rays():
  # View 0 looks down +z from the origin (mask rays reach z 1..3); view 1 down +x from (-2, 0, 2): x -1..1.
  views = [_view([0., 0., 0.], [0., 0., 1.], [1, 0]), _view([-2., 0., 2.], [1., 0., 0.], [1, 1])]
  rays = types.SimpleNamespace(origins=np.stack([v[0] for v in views]), directions=np.stack([v[1] for v in views]),
                               near=np.ones((2, 1, 2, 1)), far=np.full((2, 1, 2, 1), 3.))
  test_set = types.SimpleNamespace(ids=[0, 1], rays=rays, masks=np.stack([v[2] for v in views]))
  np.testing.assert_allclose(dtu.mask_region(test_set), [[0., 0., 2.], [0., 0., 2.]])
  test_set.masks = np.zeros_like(test_set.masks)
  assert dtu.mask_region(test_set) is None  # No region of its own: the tool asks for --bounds.


@pytest.mark.skipif(not (SHARED_DATA / 'dtu' / 'dtu_scan24').is_dir(), reason='the shared DTU scan is absent')
def test_the_dtu_region_of_the_shared_scan_is_a_small_part_of_the_views_reach():
  config = Config(dataset_loader='dtu', data_dir=str(SHARED_DATA / 'dtu'), dtu_scan='dtu_scan24', factor=8, near=.5,
                  far=3.5, dtu_mask_path='', allow_missing_test_views=True, white_background=False)
  region = mesh_tool.scene_bounds(config, None)
  rays = datasets.load_dataset('test', config).rays
  ends = np.concatenate([rays.origins + rays.directions * .5, rays.origins + rays.directions * 3.5]).reshape(-1, 3)
  reach = np.stack([ends.min(0), ends.max(0)])
  assert np.all(region[1] > region[0]) and np.all(region[0] >= reach[0]) and np.all(region[1] <= reach[1])
  assert np.prod(region[1] - region[0]) < .05 * np.prod(reach[1] - reach[0])  # Measured: 2.2%.


# ------------------------------------------------------------------ a trained generated scene

STEPS = 400
TRAINED = [f'Config.max_steps = {STEPS}', 'Config.n_input_views = 24', 'MLP.net_depth = 4', 'MLP.net_width = 64',
           'Config.batch_size = 256', f'Config.freq_reg_end = {STEPS // 2}', f'Config.checkpoint_every = {STEPS}']


def _bindings(scene_dir, run):
  return TINY + [f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'"] + TRAINED


@pytest.fixture(scope='module')
def trained(tmp_path_factory, scene_dir):
  """(scene dir, run dir) of a small mip-NeRF FreeNeRF trained on the 24 views of the generated object scene."""
  run = tmp_path_factory.mktemp('mesh') / 'run'
  loop.train(tiny_config(scene_dir, run, *TRAINED))
  return scene_dir, run


CHAMFER_BOUND = .12
MIN_COVERAGE = .25  # Of each solid's visible surface within mesh_scores.COVERAGE_DISTANCE of the mesh.


def surface_found(scores: dict) -> bool:
  """The check a trained mesh must pass: its mean distance to the surfaces is small and each solid is found."""
  return scores['chamfer'] < CHAMFER_BOUND and all(s['coverage'] >= MIN_COVERAGE for s in scores['solids'].values())


@pytest.fixture(scope='module')
def trained_mesh(trained, tmp_path_factory):
  """(vertices [V, 3], solids, the record of tools.mesh --scores) of the trained scene's mesh."""
  scene_dir, run = trained
  out = tmp_path_factory.mktemp('mesh_out')
  status = mesh_tool.main(['--gin_configs', DEMO, '--gin_bindings', *_bindings(scene_dir, run), '--resolution', '64',
                           '--out', str(out / 'scene.ply'), '--scores', str(out / 'scores.json')])
  assert status == 0
  verts, faces, colours = ply.read(str(out / 'scene.ply'))
  assert len(faces) > 1000 and colours.std() > 10  # Coloured, not flat grey.
  solids = json.loads((scene_dir / 'scene.json').read_text())['solids']
  return verts, solids, json.loads((out / 'scores.json').read_text())


def test_the_mesh_of_a_trained_scene_lies_on_its_exact_surfaces(trained_mesh):
  verts, solids, record = trained_mesh
  assert record['level'] == pytest.approx(math.log(2.) * 16 / (6. - 2.))  # ln 2 x 16 samples / (6 - 2).
  assert (record['vertices'], record['resolution'], record['step']) == (len(verts), 64, STEPS)
  assert record['provenance']['command'].startswith('python -m tools.mesh --gin_configs ')
  scores = record['scores']
  assert scores['chamfer'] == pytest.approx(mesh_scores.score(verts, solids)['chamfer'], rel=1e-5)  # PLY: float32.
  # Measured here: Chamfer 0.086 (accuracy 0.078, completeness 0.093; the scene is 3 units across, a grid cell
  # 0.05), coverage 0.99 ground, 0.59 and 0.47 the spheres, 0.70 the box; a solid left out keeps 0.07 to 0.08
  # (the vertices of its neighbours). At level 4.35 instead the objects' tops went missing (Chamfer 0.109).
  assert surface_found(scores), scores


@pytest.mark.parametrize('kept', ['ground only', 'without the box and the small sphere'])
def test_a_mesh_missing_solids_fails_the_check_whatever_its_chamfer_distance(trained_mesh, kept):
  verts, solids, _ = trained_mesh
  nearest = np.argmin([mesh_scores.solid_distance(solid, verts) for solid in solids], 0)
  small = min((i for i, s in enumerate(solids) if s['shape'] == 'sphere'), key=lambda i: solids[i]['radius'])
  box = next(i for i, s in enumerate(solids) if s['shape'] == 'box')
  part = verts[nearest == 0] if kept == 'ground only' else verts[(nearest != box) & (nearest != small)]
  scores = mesh_scores.score(part, solids)
  # Measured: Chamfer 0.147 and 0.118, the latter within the bound (with the earlier sampling, by faces and not by
  # area, 0.117 and 0.067: both within it, the second below the whole mesh's); the missing solids' coverage fails
  # both.
  missing = [name for name, s in scores['solids'].items() if s['coverage'] < MIN_COVERAGE]
  assert len(missing) == (3 if kept == 'ground only' else 2) and not surface_found(scores), scores


def test_the_recorded_mesh_of_the_demo_finds_every_solid():
  """results/mesh/demo_object.json, from the README's mesh commands (the demo's FreeNeRF, 8 views, 192^3 grid)."""
  record = json.loads((ROOT / 'results' / 'mesh' / 'demo_object.json').read_text())
  assert record['provenance']['command'].endswith('--resolution 192 --picture out/mesh_demo/mesh.png --scores '
                                                  'results/mesh/demo_object.json')
  assert '+dirty' not in record['provenance']['commit'] and record['step'] == 700
  assert surface_found(record['scores']) and len(record['scores']['solids']) == 4, record['scores']


def _mesh_cli(capsys, *argv) -> tuple:
  """(exit status, stderr) of tools.mesh run as its command line runs it (its flags bind gin afresh)."""
  status = cli.run(lambda: mesh_tool.main(list(argv)))
  return status, capsys.readouterr().err


def _run_flags(trained, *flags):
  scene_dir, run = trained
  return ['--gin_configs', DEMO, '--gin_bindings', *_bindings(scene_dir, run), *flags]


def test_a_level_the_field_never_reaches_is_one_error_and_writes_nothing(trained, tmp_path, capsys):
  out = tmp_path / 'none.ply'
  status, err = _mesh_cli(capsys, *_run_flags(trained, '--resolution', '16', '--level', '1e6', '--out', str(out)))
  assert status == 2 and err.count('\n') == 1, err
  assert re.match(r'error: the density stays below the level 1e\+06 inside the bounds \(its minimum is \S+, its '
                  r'maximum \S+\):.* \(--level sets the level', err), err
  assert not os.path.exists(out)


def test_scores_need_the_generated_object_scene_and_never_replace_a_file(trained, tmp_path, capsys):
  status, err = _mesh_cli(capsys, '--gin_configs', DEMO, '--gin_bindings', "Config.generated_rig = 'forward'",
                          'Config.near = 0.', 'Config.far = 1.', '--scores', str(tmp_path / 's.json'))
  assert status == 2 and err.startswith('error: --scores ') and "got 'generated' ('forward' rig)" in err, err
  (tmp_path / 's.json').write_text('{}')
  status, err = _mesh_cli(capsys, *_run_flags(trained, '--scores', str(tmp_path / 's.json')))
  assert status == 2 and 's.json\' exists' in err and (tmp_path / 's.json').read_text() == '{}', err


@pytest.mark.parametrize('level', ['nan', 'inf', '-1', '0'])
def test_a_level_that_is_not_a_positive_finite_density_is_refused(level, capsys):
  status, err = _mesh_cli(capsys, '--level', level)
  assert status == 2 and err == (f'error: --level {float(level)}: expected a positive finite density (the density '
                                 'is >= 0)\n')


def test_a_resolution_beyond_the_host_memory_is_refused_with_the_largest_that_fits(monkeypatch, capsys):
  monkeypatch.setattr(out_of_memory, 'host_available_bytes', lambda: 2**30)
  status, err = _mesh_cli(capsys, '--resolution', '100000')
  largest = int(math.sqrt(2**30 / (33 * mesh.HOST_BYTES_PER_POINT)))  # 33 z-planes a slab.
  assert status == 2 and err == (f'error: --resolution 100000 needs {out_of_memory.size_text(mesh.host_bytes(100000))} '
                                 f'of host memory, 1.00 GiB is available: the largest --resolution that fits is '
                                 f'{largest}\n')
  assert mesh.host_bytes(largest) <= 2**30 < mesh.host_bytes(largest + 1)


def test_a_chunk_beyond_the_device_memory_is_refused_with_the_largest_that_fits(trained, monkeypatch, capsys):
  available = 64 * 2**20
  monkeypatch.setattr(out_of_memory, 'device_available_bytes', lambda device, host: available)
  status, err = _mesh_cli(capsys, *_run_flags(trained, '--resolution', '64', '--chunk', '200000000'))
  found = re.fullmatch(r'error: --chunk (\d+) needs (.*) of device memory, 64.0 MiB is available: the largest --chunk '
                       r'that fits is (\d+)\n', err)
  assert status == 2 and found, err
  chunk, largest = int(found[1]), int(found[3])
  assert chunk == mesh.slab_points(64) and 0 < largest < chunk  # Capped at a slab's points, then measured.
  config = tiny_config(trained[0], trained[1], *TRAINED)
  example = datasets.load_dataset('train', config).rays
  model, state = checkpoints.restore_model(config, str(trained[1]), jax.tree.map(lambda x: x[0, 0, :8], example))
  assert mesh.field_functions(config, model, state.params, int(state.step), .1, largest)[2] <= available
