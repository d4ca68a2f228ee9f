"""The viewer's pure parts (tools/view/): viser's cameras against this project's, rays of any camera equal to the
loaders', frame sizes, the comparison's panels, chunk sizes; the render thread and the checkpoint watcher with
stand-in runs. None of these needs viser."""

import dataclasses
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from internal import datasets
from internal import runs as internal_runs
from internal.cameras import algebra, caster, corrections
from internal.cameras.records import Cameras, RaySpace
from internal.datasets import base, blender, generated, llff
from internal.evaluation import vis
from internal.rays import Rays
from test_checkpoints import DEMO, TINY
from tools.view import app, cameras, frames, layout, resolution, runs, service, watch
from tools.view import __main__ as view_main


def random_rotation(seed: int) -> np.ndarray:
  q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
  return q * np.sign(np.linalg.det(q))


def opengl_camera(seed: int) -> np.ndarray:
  """[3,4] a camera with OpenGL axes at a random pose."""
  return np.concatenate([random_rotation(seed), np.random.default_rng(seed + 100).normal(size=(3, 1))], 1)


def assert_rays_equal(a: Rays, b: Rays):
  for name, x, y in zip(Rays._fields, a, b):
    np.testing.assert_array_equal(x, y, err_msg=name)


def loader_rays(camtoworld, pixtocam, space: RaySpace) -> Rays:
  """Rays [H,W,...] of one camera as a loader casts its images' (caster.image_rays)."""
  return Rays(*[x[0] for x in caster.image_rays(Cameras(camtoworld[None], pixtocam[None]), space)])


# ---------------------------------------------------------------- cameras


def test_a_viser_camera_is_a_centred_pinhole_of_its_vertical_field_of_view():
  c2w, pixtocam = cameras.view_camera([1., 0., 0., 0.], [1., 2., 3.], np.radians(60.), 30, 40)
  np.testing.assert_array_equal(c2w, [[1., 0., 0., 1.], [0., 1., 0., 2.], [0., 0., 1., 3.]])
  focal = 15. / np.tan(np.radians(30.))
  np.testing.assert_allclose(pixtocam, algebra.focal_pixtocam(focal, 30, 40), rtol=1e-15)
  assert cameras.field_of_view(pixtocam, 30) == pytest.approx(np.radians(60.), rel=1e-14)


def test_opengl_cameras_turn_into_opencv_axes_with_the_same_centre():
  gl = opengl_camera(0)
  cv = cameras.to_opencv(gl[None], True)[0]
  np.testing.assert_array_equal(cv[:, 3], gl[:, 3])
  np.testing.assert_array_equal(cv[:, 2], -gl[:, 2])  # OpenCV looks down +z where OpenGL looks down -z.
  np.testing.assert_array_equal(cameras.to_opencv(cv[None], False)[0], cv)


def viser_camera(c2w_opencv, pixtocam, height, width):
  """(c2w, pixtocam) after the trip through viser's representation (a quaternion, a vertical field of view)."""
  view = frames.View(tuple(algebra.rotation_to_quaternion(c2w_opencv[:, :3])), tuple(c2w_opencv[:, 3]),
                     cameras.field_of_view(pixtocam, height), width / height)
  return cameras.view_camera(view.wxyz, view.position, view.fov, height, width)


def test_world_rays_of_a_viser_camera_equal_blenders_bit_for_bit():
  gl, (height, width) = opengl_camera(1), (12, 16)
  pixtocam = algebra.focal_pixtocam(20., height, width)
  space = RaySpace(opengl=True, near=2., far=6., height=height, width=width, pixel_offset=.25)  # Blender's.
  assert_rays_equal(cameras.camera_rays(*viser_camera(cameras.to_opencv(gl[None], True)[0], pixtocam, height,
                                                      width), height, width, space), loader_rays(gl, pixtocam, space))


def test_world_rays_of_another_size_are_the_loaders_at_that_size():
  gl, (height, width) = opengl_camera(3), (12, 16)
  space = RaySpace(opengl=True, near=2., far=6., height=height, width=width)
  small = algebra.focal_pixtocam(9., 5, 7)  # The released radii of the last row and column at the frame's size.
  got = cameras.camera_rays(cameras.to_opencv(gl[None], True)[0], small, 5, 7, space)
  assert_rays_equal(got, loader_rays(gl, small, dataclasses.replace(space, height=5, width=7)))


def test_dtu_rays_of_a_camera_equal_the_loaders_with_their_origins_on_the_plane():
  cv, (height, width) = cameras.to_opencv(opengl_camera(2)[None], False)[0], (10, 14)
  pixtocam = algebra.focal_pixtocam(17., height, width)
  space = RaySpace(opengl=False, near=.5, far=3.5, height=height, width=width, plane_z=.3)  # DTU's.
  got = cameras.camera_rays(cv, pixtocam, height, width, space)
  assert_rays_equal(got, loader_rays(cv, pixtocam, space))
  np.testing.assert_allclose(got.origins[..., 2], .3, atol=1e-6)


def forward_camera() -> np.ndarray:
  """[3,4] an OpenGL camera near LLFF's reference, looking down -z."""
  return np.concatenate([corrections.so3_exp(np.array([.05, -.03, .02])), [[.1], [-.2], [.3]]], 1)


def test_ndc_rays_of_a_camera_equal_llffs_in_the_training_views_ndc_space_bit_for_bit():
  gl, focal, (height, width) = forward_camera(), 18.3, (16, 20)
  pixtocam = algebra.focal_pixtocam(focal, height, width)
  space = llff.ray_space(focal, height, width)
  got = cameras.camera_rays(*viser_camera(cameras.to_opencv(gl[None], True)[0], pixtocam, height, width), height,
                            width, space)
  assert_rays_equal(got, loader_rays(gl, pixtocam, space))


@pytest.mark.parametrize('scale', [.5, 2.])
def test_ndc_rays_of_another_size_keep_the_training_views_ndc_space(scale):
  gl, focal, (height, width) = forward_camera(), 18.3, (16, 20)
  space = llff.ray_space(focal, height, width)
  rows, columns = int(height * scale), int(width * scale)
  pixtocam = algebra.focal_pixtocam(focal * scale, rows, columns)
  got = cameras.camera_rays(cameras.to_opencv(gl[None], True)[0], pixtocam, rows, columns, space)
  # LLFF's own rays at that size map the same (its NDC space scales with the size); every radius, the last row's
  # and column's too, from the next pixel's.
  own = dataclasses.replace(llff.ray_space(focal * scale, rows, columns), released_edges=False)
  for name, x, y in zip(Rays._fields, got, loader_rays(gl, pixtocam, own)):
    np.testing.assert_allclose(x, y, atol=1e-6, err_msg=name)


@pytest.mark.parametrize('ndc', [False, True])
def test_path_centres_are_the_cameras_centres_in_world_and_ndc_rays(ndc):
  height, width, focal = 8, 10, 9.
  pixtocam = algebra.focal_pixtocam(focal, height, width)
  poses = np.array([np.concatenate([np.eye(3), [[x], [.5 * x], [.2]]], 1) for x in (-.3, 0., .4)])  # Down -z.
  space = llff.ray_space(focal, height, width) if ndc else RaySpace(opengl=True, near=2., far=6., height=height,
                                                                    width=width)
  path = caster.image_rays(Cameras(poses, np.broadcast_to(pixtocam, (len(poses), 3, 3))), space)
  np.testing.assert_allclose(cameras.path_centres(path, space), poses[:, :, 3], atol=1e-5)


@pytest.mark.parametrize('rig', ['object', 'forward'])
def test_render_path_cameras_in_the_training_views_space_cast_render_pys_rays_bit_for_bit(rig, tmp_path):
  """The object rig's world rays and the forward rig's NDC rays (the training views' own NDC focal length)."""
  configs = [DEMO] + ([DEMO.replace('demo.gin', 'demo_forward.gin')] if rig == 'forward' else [])
  scene = [f"Config.data_dir = '{tmp_path}'", 'Config.generated_size = (16, 20)', 'Config.render_path_frames = 2']
  config = internal_runs.bind_fresh(configs, TINY + scene)
  space = datasets.load_dataset('train', config).space
  if rig == 'object':
    poses, pixtocam, height, width = blender.render_cameras(generated.scene(config), base.render_factor(config))
    path = algebra.orbit_path(poses, 2)
  else:
    poses, bounds, _, pixtocam, height, width = llff.render_cameras(generated.scene(config),
                                                                    base.render_factor(config))
    path = algebra.spiral_path_llff(poses, bounds, 2)
  expected = datasets.render_path_rays(config)
  for frame, pose in enumerate(cameras.to_opencv(path, True)):
    assert_rays_equal(cameras.camera_rays(pose, pixtocam, height, width, space), Rays(*[x[frame] for x in expected]))


# ---------------------------------------------------------------- sizes, panels, chunks


def test_frame_sizes_follow_the_aspect_and_the_moving_size_the_budget():
  assert resolution.frame_width(64, 1.25) == 80 and resolution.frame_width(1, .1) == 1
  assert resolution.budget_rows(1e-6, 1.) == int(np.sqrt(resolution.FRAME_BUDGET / 1e-6))
  assert resolution.moving_rows('auto', 400, 1e-5, 1.) == 141                 # 141^2 rays in 0.2 s.
  assert resolution.moving_rows('auto', 400, 1., 1.) == resolution.MIN_ROWS  # Slow: never below MIN_ROWS.
  assert resolution.moving_rows('auto', 8, 1., 1.) == 8                      # ... or the full size when smaller.
  assert resolution.moving_rows('auto', 400, 0., 1.) == 100                   # No measurement yet: a quarter.
  assert resolution.moving_rows('1/4', 400, 1e-9, 1.) == 100
  assert resolution.updated_speed(0., 2., 1000) == .002
  assert resolution.updated_speed(.002, 4., 1000) == pytest.approx(.003)


def test_split_and_side_by_side_panels_cover_the_frame():
  assert layout.panels(None, 9) == [(0, 0, 9)]
  assert layout.panels('split', 10, .3) == [(0, 0, 3), (1, 3, 10)]
  assert layout.panels('split', 10, 0.) == [(1, 0, 10)] and layout.panels('split', 10, 1.) == [(0, 0, 10)]
  assert layout.panels('side by side', 10) == [(0, 2, 7), (1, 2, 7)]  # The centre half of the view, each.
  assert layout.panels('side by side', 9) == [(0, 2, 6), (1, 2, 7)]
  with pytest.raises(ValueError, match='layout'):
    layout.panels('above', 10)


def test_compose_puts_the_panels_side_by_side_with_a_divider():
  left, right = np.zeros((2, 3, 3)), np.full((2, 4, 3), .5)
  frame = layout.compose([left, right], 'split')
  assert frame.shape == (2, 7, 3)
  np.testing.assert_array_equal(frame[:, :3], left)
  np.testing.assert_array_equal(frame[:, 3], layout.DIVIDER)
  np.testing.assert_array_equal(frame[:, 4:], right[:, 1:])
  np.testing.assert_array_equal(layout.compose([left], None), left)


def test_chunks_are_powers_of_two_within_the_configured_chunk():
  assert [runs.chunk_size(n, 4096) for n in (1, 256, 257, 3000, 5000)] == [256, 256, 512, 4096, 4096]
  assert runs.chunk_size(5000, 1280) == 1280 and runs.chunk_size(10, 100) == 100


def test_depth_pictures_of_two_panels_share_one_range():
  near, far = {'distance_mean': np.full((2, 2), 2.)}, {'distance_mean': np.full((2, 2), 4.)}
  a, b = frames.pictures([near, far], 'depth')
  lo, hi = vis.depth_range(np.array([2., 4.]))
  np.testing.assert_array_equal(a, vis.colorize_depth(near['distance_mean'], (lo, hi)))
  assert not np.array_equal(a, b)
  with pytest.raises(ValueError, match='output'):
    frames.pictures([near], 'normals')


# ---------------------------------------------------------------- the render thread, with stand-in runs


class FakeRun:
  """Renders the rays' view directions as colour, taking `seconds` a call; counts its calls."""

  def __init__(self, seconds=0., step=7):
    self.space = RaySpace(opengl=False, near=1., far=2., height=1, width=1)  # World rays: any frame size.
    self.seconds, self.step, self.calls = seconds, step, []

  def compiled_shapes(self):
    return frozenset()

  def render(self, rays):
    self.calls.append(rays.origins.shape[:2])
    time.sleep(self.seconds)
    return {'rgb': .5 + .5 * rays.viewdirs, 'acc': np.ones(rays.origins.shape[:2]),
            'distance_mean': np.ones(rays.origins.shape[:2])}


def view_at(x: float) -> frames.View:
  return frames.View((1., 0., 0., 0.), (x, 0., 0.), 1., 1.25)


class Screen:
  """What a ClientView sends: (image, format) in order."""

  def __init__(self):
    self.shown, self.lines, self.event = [], [], threading.Event()

  def send(self, image, image_format):
    self.shown.append((image, image_format))
    self.event.set()

  def wait_for(self, count, timeout=20.):
    end = time.time() + timeout
    while len(self.shown) < count and time.time() < end:
      time.sleep(.01)
    return self.shown


def test_a_moving_frame_then_the_full_size_once_the_camera_rests():
  run, screen = FakeRun(), Screen()
  client = service.ClientView([run], lambda: frames.Options(moving='1/2', full_rows=32), screen.send,
                              screen.lines.append)
  client.request(view_at(0.))
  shown = screen.wait_for(2)
  client.stop()
  assert [(image.shape, fmt) for image, fmt in shown] == [((16, 20, 3), 'jpeg'), ((32, 40, 3), 'png')]
  assert 'step 7: 32 x 40' in screen.lines[-1] and 'full size' in screen.lines[-1]
  expected, _ = frames.render_frame([run], view_at(0.), 32, frames.Options(full_rows=32))
  np.testing.assert_array_equal(shown[-1][0], expected)


def test_requests_overtaken_while_a_frame_renders_are_dropped():
  run, screen = FakeRun(seconds=.3), Screen()
  client = service.ClientView([run], lambda: frames.Options(moving='full', full_rows=4), screen.send,
                              screen.lines.append)
  client.request(view_at(0.))
  time.sleep(.1)  # The first frame is rendering: the next three requests arrive meanwhile.
  for x in (1., 2., 3.):
    client.request(view_at(x))
  shown = screen.wait_for(2)
  time.sleep(1.)
  client.stop()
  assert len(screen.shown) == 2  # The first view and the newest; views 1 and 2 never rendered.
  expected, _ = frames.render_frame([run], view_at(3.), 4, frames.Options(full_rows=4))
  np.testing.assert_array_equal(shown[-1][0], expected)


def test_the_same_camera_sent_again_is_no_new_frame():
  run, screen = FakeRun(), Screen()
  client = service.ClientView([run], lambda: frames.Options(moving='1/2', full_rows=32), screen.send,
                              screen.lines.append)
  client.request(view_at(0.))
  screen.wait_for(2)
  client.request(view_at(0.))  # A browser repeats its camera now and then.
  time.sleep(service.REST + .5)
  client.request()             # A setting changed: the same view again, moving then full.
  screen.wait_for(4)
  time.sleep(service.REST + .5)
  client.stop()
  assert [fmt for _, fmt in screen.shown] == ['jpeg', 'png', 'jpeg', 'png']


def test_a_full_frame_stops_between_bands_when_a_newer_request_arrives(monkeypatch):
  monkeypatch.setattr(frames, 'BAND_RAYS', 20)  # One row a band.
  run, screen = FakeRun(seconds=.05), Screen()
  client = service.ClientView([run], lambda: frames.Options(moving='1/8', full_rows=40), screen.send,
                              screen.lines.append)
  client.request(view_at(0.))
  screen.wait_for(1)
  time.sleep(service.REST + .2)  # The full frame (40 bands, 2 s) has started.
  client.request(view_at(1.))
  shown = screen.wait_for(3, timeout=30.)
  client.stop()
  assert [image.shape[0] for image, _ in shown[:3]] == [12, 12, 40]  # The first full frame was never finished.
  assert len(run.calls) < 12 + 12 + 40 + 40


# ---------------------------------------------------------------- the checkpoint watcher, with stand-in runs


class SteppingRun:
  def __init__(self, newer=(), error=None):
    self.newer, self.error, self.step = list(newer), error, 1

  def reload(self):
    if self.error:
      raise self.error
    if self.newer:
      self.step = self.newer.pop(0)
      return True
    return False


def test_the_watcher_reloads_newer_checkpoints_on_its_interval_and_when_asked():
  reloaded, errors = [], []
  run = SteppingRun(newer=[5, 9])
  watcher = watch.CheckpointWatcher([run], 0., reloaded.append, errors.append)
  assert watcher.check() == [run] and run.step == 5
  watcher.set_interval(.05)
  end = time.time() + 10
  while run.step != 9 and time.time() < end:
    time.sleep(.01)
  watcher.stop()
  assert run.step == 9 and reloaded == [[run], [run]] and errors == []


def test_the_watcher_reports_a_checkpoint_it_cannot_read_in_one_line():
  errors = []
  watcher = watch.CheckpointWatcher([SteppingRun(error=FileNotFoundError('no checkpoint in x'))], 0.,
                                    lambda runs: None, errors.append)
  assert watcher.check() == []
  watcher.stop()
  assert errors == ['checkpoints: no checkpoint in x']


# ---------------------------------------------------------------- the command line


def test_compare_flags_take_several_values_after_an_equals_sign():
  args = view_main.parse_args(['--compare_bindings=A = 1', 'B = 2', '--compare_configs=x.gin', '--port', '9'])
  assert args.compare_bindings == ['A = 1', 'B = 2'] and args.compare_configs == ['x.gin'] and args.port == 9
  with pytest.raises(ValueError, match='--height'):
    view_main.parse_args(['--height', '0'])


def test_the_address_line_says_who_can_reach_the_page():
  assert view_main.address('127.0.0.1', 8080) == 'http://127.0.0.1:8080 (this machine only)'
  assert 'every network interface' in view_main.address('0.0.0.0', 8080)


def test_a_port_in_use_an_address_not_of_this_machine_and_a_missing_viser_are_named():
  with socket.socket() as taken:
    taken.bind(('127.0.0.1', 0))
    taken.listen()
    port = taken.getsockname()[1]
    with pytest.raises(app.ViewerError, match=f'--port {port}: another program listens on it'):
      app.check_address('127.0.0.1', port)
  app.check_address('127.0.0.1', port)  # Closed: free again.
  with pytest.raises(app.ViewerError, match="--host '203.0.113.7' --port 9: cannot listen there"):
    app.check_address('203.0.113.7', 9)  # An address of the documentation range, no machine's here.


def test_the_viewer_without_viser_says_how_to_install_it(monkeypatch):
  monkeypatch.setitem(sys.modules, 'viser', None)  # As if it were not installed.
  with pytest.raises(app.ViewerError, match='pip install -r requirements-viewer.txt'):
    app.require_viser()


SIGINT_ON_ANOTHER_THREAD = '''
import signal, threading, time
from tools.view.__main__ import wait_for_ctrl_c
def other():
  time.sleep(.5)
  signal.pthread_kill(threading.get_ident(), signal.SIGINT)  # The kernel may give a Ctrl-C to any thread.
threading.Thread(target=other, daemon=True).start()
try:
  wait_for_ctrl_c()
except KeyboardInterrupt:
  print('stopped')
'''


def test_ctrl_c_that_lands_on_another_thread_stops_the_wait():
  root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
  proc = subprocess.run([sys.executable, '-c', SIGINT_ON_ANOTHER_THREAD], cwd=root, capture_output=True, text=True,
                        timeout=60, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
  assert proc.stdout == 'stopped\n', proc.stderr
