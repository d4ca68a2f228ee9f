"""Point clouds of a field (internal/geometry/points.py, tools/points.py): from the generated scene's exact depths
the points lie on its surfaces and the views agree; NDC depths come back to the world; the COLMAP model loads in
the capture loader; the tool on a trained run, its memory check and its refusals."""

import os
import tracemalloc

import gin
import numpy as np
import pytest

from internal import cli
from internal.configs import Config
from internal.cameras import algebra, caster
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import load_dataset, scene_generator
from internal.datasets import capture as capture_loader
from internal.geometry import mesh_scores, ply
from internal.geometry import points as points_lib
from internal.pipeline import loop
from internal.rays import Rays
from internal.run import out_of_memory
from test_checkpoints import DEMO, TINY, tiny_config
from test_read_only import read_only
from tools import points as points_tool


def _exact_views(data):
  """points_lib.Views of a world-ray dataset's views from its exact depths (opaque where a ray hits)."""
  views = []
  for i in range(len(data.ids)):
    depth = data.depths[i].astype(np.float64)
    rays = data.rays
    view = points_lib.View(points=rays.origins[i] + depth[..., None] * rays.directions[i], rgb=data.images[i],
                           acc=(depth > 0).astype(np.float32), normals=None, name=f'view{i}.png')
    centre = rays.viewdirs[i][data.height // 2, data.width // 2].astype(np.float64)
    view.camtoworld = points_lib.opencv_camtoworld(data.camtoworlds[i], centre)
    view.intrinsics = np.linalg.inv(data.pixtocams[i].astype(np.float64))
    views.append(view)
  return views


@pytest.fixture(name='object_views', scope='module')
def fixture_object_views(tmp_path_factory):
  root = tmp_path_factory.mktemp('points')
  config = Config(data_dir=str(root / 'scene'), n_input_views=6, generated_size=(48, 60))
  data = load_dataset('train', config, ground_truth=True)
  return config, data, _exact_views(data)


def test_exact_depths_give_points_on_the_surfaces_that_the_views_agree_on(object_views):
  config, data, views = object_views
  pixel, z = points_lib.project(views[0], views[0].points.reshape(-1, 3))
  rows, cols = np.mgrid[:data.height, :data.width]
  hit = data.depths[0].reshape(-1) > 0
  np.testing.assert_allclose(pixel[hit], np.stack([cols, rows], -1).reshape(-1, 2)[hit] + .5, atol=1e-4)
  np.testing.assert_allclose(z[hit], data.depths[0].reshape(-1)[hit], rtol=1e-5)
  found = points_lib.cloud(views, [], .5, .02, 2, 10**6, np.random.default_rng(0))
  solids = scene_generator.read_scene(config.data_dir)['solids']
  scores = mesh_scores.score(found['points'], solids)
  assert scores['accuracy'] < 1e-3  # On the exact surfaces.
  opaque = sum(int((v.acc > .5).sum()) for v in views)
  assert .5 * opaque < len(found['points']) <= opaque  # Most pixels are seen by a second view.
  assert np.all(found['agrees'].sum(1) >= 2)
  capped = points_lib.cloud(views, [], .5, .02, 2, 600, np.random.default_rng(0))
  assert len(capped['points']) == 600 and np.all(np.isin(capped['points'], found['points']).all(1))


def test_a_lone_view_has_no_points_and_min_views_one_keeps_them_all(object_views):
  _, _, views = object_views
  assert len(points_lib.cloud(views[:1], [], .5, .02, 2, 10**6, np.random.default_rng(0))['points']) == 0
  lone = points_lib.cloud(views[:1], [], .5, .02, 1, 10**6, np.random.default_rng(0))
  assert len(lone['points']) == int((views[0].acc > .5).sum())


def test_ndc_depths_come_back_to_the_world():
  c2w = np.array([[1., 0., 0., .1], [0., 1., 0., -.2], [0., 0., 1., .3]])  # OpenGL, looking down -z.
  focal, height, width = 30., 12, 16
  space = RaySpace(opengl=True, near=0., far=1., height=height, width=width, ndc_focal=focal)
  camera = Cameras(c2w[None], algebra.focal_pixtocam(focal, height, width)[None])
  rays = Rays(*[x[0] for x in caster.image_rays(camera, space)])
  depth = np.random.default_rng(0).uniform(1.5, 9., (height, width))  # World t along viewdirs (camera z = 1).
  world = c2w[:, 3] + depth[..., None] * rays.viewdirs
  ndc_t = (1. + 2. / world[..., 2] - rays.origins[..., 2]) / rays.directions[..., 2]
  np.testing.assert_allclose(points_lib.world_points(rays, ndc_t, c2w, True), world, rtol=1e-5, atol=1e-5)


def test_the_colmap_model_loads_in_the_capture_loader_with_the_same_cameras(object_views, tmp_path):
  _, data, views = object_views
  found = points_lib.cloud(views, [], .5, .02, 2, 5000, np.random.default_rng(0))
  model = points_lib.colmap_of(views, [(data.height, data.width)] * len(views), found)
  os.makedirs(tmp_path / 'capture' / 'images')
  for view, path in zip(views, data.image_paths):
    os.link(path, tmp_path / 'capture' / 'images' / view.name)
  points_tool.write_colmap(str(tmp_path / 'capture'), model, [], text=False)
  config = Config(dataset_loader='capture', data_dir=str(tmp_path / 'capture'), n_input_views=0, llffhold=3,
                  white_background=False)
  capture = capture_loader.read_capture(config)
  assert capture.names == sorted(v.name for v in views) and len(capture.points) == len(found['points'])
  # The loader's frame is a similarity of the run's: relative camera distances and angles are kept.
  run = np.stack([v.camtoworld[:, 3] for v in sorted(views, key=lambda v: v.name)])
  read = capture.camtoworlds[:, :, 3]
  ratio = np.linalg.norm(read[1:] - read[0], axis=-1) / np.linalg.norm(run[1:] - run[0], axis=-1)
  np.testing.assert_allclose(ratio, ratio[0], rtol=1e-6)
  train = load_dataset('train', config)  # Its images load against its cameras.
  assert train.images.shape[1:3] == (data.height, data.width)


def _tool(*argv):
  """tools.points' main on argv, gin cleared first (the flags parse the configs again)."""
  gin.clear_config()
  return points_tool.main(list(argv))


def test_the_tool_writes_a_ply_and_a_colmap_model_of_a_trained_run_and_refuses_to_replace_them(tmp_path, capsys):
  bindings = [f"Config.data_dir = '{tmp_path / 'scene'}'", f"Config.checkpoint_dir = '{tmp_path / 'run'}'",
              'Config.max_steps = 20', 'Config.n_input_views = 4', 'Config.curve_every = 0',
              'Config.freq_reg_end = 10', 'Config.generated_size = (24, 32)']
  loop.train(tiny_config(tmp_path / 'scene', tmp_path / 'run', *bindings))
  common = ['--gin_configs', DEMO, '--gin_bindings', *TINY, *bindings, '--min_opacity', '.5', '--tolerance', '.1']
  out, folder = tmp_path / 'cloud.ply', tmp_path / 'colmap'
  assert _tool(*common, '--out', str(out), '--colmap', str(folder), '--path_views', '2',
               '--picture', str(tmp_path / 'cloud.png')) == 0
  points, colours, normals = ply.read_points(str(out))
  assert len(points) > 50 and colours.dtype == np.uint8 and normals is not None
  np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1., atol=1e-3)
  capture = Config(dataset_loader='capture', data_dir=str(folder), n_input_views=0, llffhold=3,
                   white_background=False)
  assert len(load_dataset('train', capture).ids) + len(load_dataset('test', capture).ids) == 4
  assert len(capture_loader.read_capture(capture).points) == len(points)
  with pytest.raises(FileExistsError, match='--out .*cloud.ply.* exists'):
    _tool(*common, '--out', str(out))
  with pytest.raises(FileExistsError, match='--colmap .*colmap.* holds files'):
    _tool(*common, '--out', str(tmp_path / 'other.ply'), '--colmap', str(folder))
  assert cli.run(lambda: _tool(*common, '--out', str(tmp_path / 'x.ply'), '--max_points', '0')) == 2
  (tmp_path / 'shared').mkdir()
  capsys.readouterr()
  with read_only(tmp_path / 'shared'):  # Named before the views render, nothing written.
    for flags, named in ((['--out', str(tmp_path / 'shared' / 'p.ply')], f"--out '{tmp_path / 'shared' / 'p.ply'}'"),
                         (['--out', str(tmp_path / 'p.ply'), '--colmap', str(tmp_path / 'shared' / 'model')],
                          f"--colmap '{tmp_path / 'shared' / 'model'}'")):
      assert cli.run(lambda f=flags: _tool(*common, *f)) == 2
      err = capsys.readouterr().err
      assert err == (f"error: {named} cannot be written: Read-only file system ('{tmp_path / 'shared'}'); choose a "
                     'folder you can write to\n'), err
  assert not os.listdir(tmp_path / 'shared') and not (tmp_path / 'p.ply').exists()


def test_memory_is_checked_first_naming_max_points(monkeypatch):
  monkeypatch.setattr(out_of_memory, 'host_available_bytes', lambda: 10 * 2**20)
  with pytest.raises(ValueError, match=r'--max_points 1000000 with 4 training views needs .* the largest --max_points '
                                       r'that fits is \d+'):
    points_tool.check_memory(4, 64 * 80, 64 * 80, 10**6)
  with pytest.raises(ValueError, match='no --max_points fits: the 40 training views of 307200 pixels alone'):
    points_tool.check_memory(40, 480 * 640, 480 * 640, 10)
  points_tool.check_memory(4, 64 * 80, 64 * 80, 1000)


def test_host_bytes_bound_the_measured_peak(object_views):
  _, data, views = object_views
  tracemalloc.start()
  points_lib.cloud(views, [], .5, .02, 2, 10**6, np.random.default_rng(0))
  peak = tracemalloc.get_traced_memory()[1]
  tracemalloc.stop()
  pixels = data.height * data.width
  kept = sum(int((v.acc > .5).sum()) for v in views)
  assert peak <= points_lib.host_bytes(len(views), pixels, pixels, kept), peak


@pytest.mark.parametrize('seen, z, agrees', [
    (100., 101., True),    # 1% apart: agree at 2%, though 1 unit is far more than 0.02.
    (.5, .515, False),     # 3% apart: disagree at 2%, though 0.015 is less than 0.02.
    (.5, .509, True),
])
def test_the_depth_agreement_is_relative(seen, z, agrees):
  view = points_lib.View(points=None, rgb=None, acc=None, normals=None, camtoworld=np.eye(3, 4),
                         intrinsics=np.array([[10., 0., 2.], [0., 10., 2.], [0., 0., 1.]]))
  found, _ = points_lib.agreement([view], [np.full((4, 4), seen)], np.array([[0., 0., z]]), .02)
  assert found.tolist() == [[agrees]]
