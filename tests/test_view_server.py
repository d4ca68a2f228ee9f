"""The viewer's server (tools/view/) on trained tiny runs, driven as a browser drives it: viser's websocket
protocol (msgpack messages: the camera in, frames and the panel out). A camera sent comes back as render.py's frame
of that camera at that size; two runs compare in one frame; a newer checkpoint is loaded when asked; bad input and
Ctrl-C end in one line; and where Chromium is installed, headless Chromium opens the page and shows the frame.
Skipped, saying so, without viser (pip install -r requirements-viewer.txt)."""

import contextlib
import io
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from PIL import Image

from internal import cli
from internal import interrupt
from internal import runs
from internal.cameras import algebra
from internal.datasets import base, blender, generated, llff
from internal.evaluation import render_path
from internal.pipeline import loop
from test_checkpoints import DEMO, ROOT, TINY, tiny_config

viser = pytest.importorskip('viser', reason='the viewer needs viser (pip install -r requirements-viewer.txt)')
msgspec = pytest.importorskip('msgspec')
from websockets.sync.client import connect  # pylint: disable=wrong-import-position  (installed with viser)

from tools.view import app, layout, screenshot  # pylint: disable=wrong-import-position
from tools.view import __main__ as view_main  # pylint: disable=wrong-import-position

FORWARD = DEMO.replace('demo.gin', 'demo_forward.gin')
STEPS = ['Config.max_steps = 4', 'Config.checkpoint_every = 2', 'Config.curve_every = 0',
         'Config.render_path_frames = 2']
NERF = ['NerfMLP.net_depth = 2', 'NerfMLP.net_width = 32', 'NerfMLP.net_width_viewdirs = 16',
        'NerfModel.num_coarse_samples = 8', 'NerfModel.num_fine_samples = 8', 'Config.generated_size = (16, 20)']
QUIET = 2.5  # Seconds without a frame after which the viewer has shown its last one.


def bindings(scene, run, *extra) -> list:
  return TINY + [f"Config.data_dir = '{scene}'", f"Config.checkpoint_dir = '{run}'"] + STEPS + list(extra)


def reference_frames(configs, flags) -> list:
  """render.py's colour frames (uint8 [H,W,3]) of a run, as it writes them."""
  out = render_path.render(runs.bind_fresh(configs, flags))
  return [np.asarray(Image.open(os.path.join(out, f'color_{f:03d}.png'))) for f in range(2)]


@pytest.fixture(name='trained', scope='module')
def fixture_trained(tmp_path_factory):
  """{'root', 'object': flags of a 4-step object-rig run (checkpoints 2 and 4), 'forward': flags of a 4-step
  forward-rig run, and each run's render.py frames}."""
  root = tmp_path_factory.mktemp('view')
  found = {'root': root}
  for rig, configs, extra in (('object', [DEMO], []), ('forward', [DEMO, FORWARD], NERF)):
    flags = bindings(root / f'scene_{rig}', root / f'run_{rig}', *extra)
    loop.train(runs.bind_fresh(configs, flags))
    found[rig] = {'configs': configs, 'flags': flags, 'frames': reference_frames(configs, flags)}
  return found


def at_step_2(trained, name: str) -> dict:
  """A copy of the object run holding only its step-2 checkpoint, its flags, its render.py frames and the step-4
  checkpoint set aside ('held')."""
  root = trained['root']
  run, held = root / name, root / f'{name}_held'
  shutil.copytree(root / 'run_object', run)
  shutil.move(run / 'checkpoints' / '4', held)
  flags = bindings(root / 'scene_object', run)
  return {'configs': [DEMO], 'flags': flags, 'run': run, 'held': held, 'frames': reference_frames([DEMO], flags)}


def free_port() -> int:
  with socket.socket() as probe:
    probe.bind(('127.0.0.1', 0))
    return probe.getsockname()[1]


@contextlib.contextmanager
def viewer(configs, flags, *extra):
  """A running viewer (in this process) of the run of configs and flags; yields its port."""
  port = free_port()
  started, _ = view_main.serve(['--gin_configs', *configs, '--gin_bindings', *flags, '--port', str(port),
                                '--check_every', '0', *extra])
  try:
    yield port
  finally:
    started.stop()


class Browser:
  """A websocket client as viser's page is one: sends its camera and panel changes, keeps every message."""

  def __init__(self, ws):
    self.ws = ws
    self.messages, self.lock = [], threading.Lock()
    self.reader = threading.Thread(target=self._read, daemon=True)
    self.reader.start()
    # The page's first camera makes it a client: the viewer moves it to the first test camera and renders that.
    self.send_camera({'wxyz': [1., 0., 0., 0.], 'position': [0., 0., 5.], 'fov': 1., 'aspect': 1.})
    self.last_frame(0.)

  def _read(self):
    try:
      for raw in self.ws:
        with self.lock:
          self.messages.extend((time.monotonic(), m) for m in msgspec.msgpack.decode(raw))
    except Exception:  # pylint: disable=broad-except  (the connection closed)
      pass

  def send(self, message: dict):
    self.ws.send(msgspec.msgpack.encode(message))

  def send_camera(self, camera: dict):
    self.send({'type': 'ViewerCameraMessage', 'near': .01, 'far': 1000., 'look_at': [0., 0., 0.],
               'up_direction': [0., 0., 1.], **camera})

  def set_control(self, label: str, value):
    """Changes the panel's control named label (a button: clicks it)."""
    with self.lock:
      uuid = next(m['uuid'] for _, m in self.messages if m.get('props', {}).get('label') == label)
    self.send({'type': 'GuiUpdateMessage', 'uuid': uuid, 'updates': {'value': value}})

  def frames(self, since: float = 0.) -> list:
    with self.lock:
      return [(t, m['media_type'], np.asarray(Image.open(io.BytesIO(m['rgb_data']))))
              for t, m in self.messages if m['type'] == 'BackgroundImageMessage' and m['rgb_data'] and t > since]

  def last_frame(self, since: float, timeout: float = 300.) -> tuple:
    """(media type, image) of the last frame after since once it is a full-size one (PNG; moving frames are JPEG)
    and none came for QUIET seconds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
      shown = self.frames(since)
      if shown and shown[-1][1] == 'image/png' and time.monotonic() - shown[-1][0] > QUIET:
        return shown[-1][1:]
      time.sleep(.1)
    raise AssertionError('no full-size frame came')


@contextlib.contextmanager
def browser(port: int):
  with connect(f'ws://127.0.0.1:{port}', max_size=None) as ws:
    yield Browser(ws)


def path_camera(config_of: str, trained, frame: int) -> dict:
  """The camera of render-path frame `frame` of the trained run config_of ('object' | 'forward'), as a browser
  sends it (viser's own quaternion of the OpenCV rotation, vertical field of view, aspect)."""
  config = runs.bind_fresh(trained[config_of]['configs'], trained[config_of]['flags'])
  if config_of == 'object':
    poses, pixtocam, height, width = blender.render_cameras(generated.scene(config), base.render_factor(config))
    pose = algebra.orbit_path(poses, config.render_path_frames)[frame]
  else:
    poses, bounds, _, pixtocam, height, width = llff.render_cameras(generated.scene(config),
                                                                    base.render_factor(config))
    pose = algebra.spiral_path_llff(poses, bounds, config.render_path_frames)[frame]
  rotation = pose[:, :3] @ np.diag([1., -1., -1.])  # OpenGL -> OpenCV axes.
  return {'wxyz': [float(v) for v in viser.transforms.SO3.from_matrix(rotation).wxyz],
          'position': [float(v) for v in pose[:, 3]],
          'fov': float(2. * np.arctan(.5 * height * pixtocam[1, 1])), 'aspect': width / height}, height


def test_a_camera_sent_as_a_browser_does_comes_back_as_render_pys_frame(trained):
  run = trained['object']
  camera, height = path_camera('object', trained, 1)
  with viewer(run['configs'], run['flags'], '--height', str(height)) as port, browser(port) as page:
    page.send_camera(camera)
    sent = time.monotonic()
    media_type, image = page.last_frame(sent)
  assert not np.array_equal(run['frames'][0], run['frames'][1])  # The frames of the path differ...
  assert media_type == 'image/png'
  np.testing.assert_array_equal(image, run['frames'][1])          # ... and the viewer's is render.py's, exactly.


def test_a_forward_scenes_ndc_frame_is_render_pys_frame_exactly(trained):
  run = trained['forward']
  camera, height = path_camera('forward', trained, 0)
  with viewer(run['configs'], run['flags'], '--height', str(height)) as port, browser(port) as page:
    page.send_camera(camera)
    media_type, image = page.last_frame(time.monotonic())
  assert media_type == 'image/png'
  np.testing.assert_array_equal(image, run['frames'][0])  # Cast in the training views' own NDC space.


def test_two_runs_compare_in_one_frame_split_and_side_by_side(trained):
  first, second = trained['object'], at_step_2(trained, 'compare')
  camera, height = path_camera('object', trained, 0)
  with viewer(first['configs'], first['flags'], '--compare_bindings', *second['flags'], '--height',
              str(height)) as port, browser(port) as page:
    page.send_camera(camera)
    _, split = page.last_frame(time.monotonic())
    changed = time.monotonic()
    page.set_control('Layout', 'side by side')
    _, side_by_side = page.last_frame(changed)
  a, b = first['frames'][0], second['frames'][0]
  assert not np.array_equal(a, b)  # Steps 4 and 2 render differently.
  width = a.shape[1]
  (_, _, cut), _ = layout.panels('split', width, .5)
  np.testing.assert_array_equal(split[:, :cut], a[:, :cut])
  np.testing.assert_array_equal(split[:, cut + 1:], b[:, cut + 1:])
  (_, start_a, end_a), (_, start_b, end_b) = layout.panels('side by side', width)
  left = end_a - start_a
  np.testing.assert_array_equal(side_by_side[:, :left], a[:, start_a:end_a])
  np.testing.assert_array_equal(side_by_side[:, left + 1:], b[:, start_b + 1:end_b])


def test_a_newer_checkpoint_is_loaded_when_asked_and_the_frame_follows(trained):
  copy = at_step_2(trained, 'reload')
  camera, height = path_camera('object', trained, 0)
  with viewer(copy['configs'], copy['flags'], '--height', str(height)) as port, browser(port) as page:
    page.send_camera(camera)
    _, before = page.last_frame(time.monotonic())
    shutil.move(copy['held'], copy['run'] / 'checkpoints' / '4')
    asked = time.monotonic()
    page.set_control('Load newer checkpoints', True)
    _, after = page.last_frame(asked)
  np.testing.assert_array_equal(before, copy['frames'][0])                # Step 2's frame...
  np.testing.assert_array_equal(after, trained['object']['frames'][0])    # ... then step 4's.


def run_main(capsys, *argv) -> tuple:
  """(status, stderr lines) of the command's main run as cli.run runs it (each run it loads binds gin afresh)."""
  status = cli.run(lambda: view_main.main(list(argv)))
  return status, capsys.readouterr().err.strip().splitlines()


def test_a_port_in_use_a_missing_run_and_another_scene_each_end_in_one_line(trained, capsys, tmp_path):
  run = trained['object']
  with socket.socket() as taken:
    taken.bind(('127.0.0.1', 0))
    taken.listen()
    port = taken.getsockname()[1]
    status, err = run_main(capsys, '--gin_configs', *run['configs'], '--gin_bindings', *run['flags'], '--port',
                           str(port))
  assert status == 2 and len(err) == 1 and err[0].startswith(f'error: --port {port}: another program listens')
  missing = bindings(trained['root'] / 'scene_object', tmp_path / 'no_run')
  status, err = run_main(capsys, '--gin_configs', DEMO, '--gin_bindings', *missing)
  assert status == 2 and len(err) == 1 and 'no_run' in err[0] and err[0].startswith('error: ')
  other = trained['forward']
  status, err = run_main(capsys, '--gin_configs', *run['configs'], '--gin_bindings', *run['flags'],
                         '--compare_configs', *other['configs'], '--compare_bindings', *other['flags'])
  assert status == 2 and len(err) == 1 and "is of scene 'generated_forward'" in err[0]


def test_ctrl_c_stops_the_viewer_in_one_line(trained):
  run = trained['object']
  command = [sys.executable, '-m', 'tools.view', '--gin_configs', *run['configs'], '--gin_bindings', *run['flags'],
             '--port', str(free_port())]
  proc = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # As a terminal starts it.
  lines = []
  for line in proc.stdout:
    lines.append(line)
    if line.startswith('viewing '):
      break
  proc.send_signal(signal.SIGINT)
  out, err = proc.communicate(timeout=120)
  assert lines[-1].startswith('viewing freenerf (step 4) at http://127.0.0.1:'), lines + [err]
  assert proc.returncode == 130 and err.strip().splitlines() == [interrupt.MESSAGE], err
  assert out == ''


@pytest.mark.skipif(shutil.which(screenshot.CHROMIUM) is None,
                    reason='chromium is not installed (apt-get install chromium): the page opens in headless Chromium')
def test_headless_chromium_opens_the_page_connects_and_shows_the_rendered_frame(trained, monkeypatch):
  sent = []
  send_to = app.Viewer._sender  # pylint: disable=protected-access

  def recording(client):
    send = send_to(client)
    return lambda image, image_format: (sent.append((image, image_format)), send(image, image_format))
  monkeypatch.setattr(app.Viewer, '_sender', staticmethod(recording))
  run = trained['object']
  with viewer(run['configs'], run['flags'], '--height', '60') as port:
    png, text = screenshot.capture(f'http://127.0.0.1:{port}', (900, 600))
  assert 'freenerf step 4' in text and '(full size)' in text  # The panel came over the websocket: connected.
  shot = np.asarray(Image.open(io.BytesIO(png)).convert('RGB'), np.float64)
  frame = next(image for image, image_format in reversed(sent) if image_format == 'png')
  # The frame fills the window behind the panel (on the right): compare the left half, the frame stretched to it.
  rows = np.arange(shot.shape[0]) * frame.shape[0] // shot.shape[0]
  cols = np.arange(shot.shape[1]) * frame.shape[1] // shot.shape[1]
  stretched = frame[rows][:, cols].astype(np.float64)
  left = slice(0, shot.shape[1] // 2)
  # The median: the frustums and their photos (white backgrounds) are drawn over parts of the frame.
  assert np.median(np.abs(shot[:, left] - stretched[:, left]).max(-1)) < 12.
  assert np.mean(np.all(shot[:, left] > 245, axis=-1)) < .5  # Not a blank (white) canvas.
