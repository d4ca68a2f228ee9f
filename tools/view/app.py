"""The viewer: a viser server on one address with the scene, the panel, a render thread per browser and the
checkpoint watcher. viser is imported here only (an extra: requirements-viewer.txt)."""

import errno
import logging
import socket

from tools.view import cameras, frames, panel as panel_lib, scene, service, watch

INSTALL = 'pip install -r requirements-viewer.txt'
LABEL = 'FreeNeRF viewer'
# A browser starts behind the first test camera by this fraction of the scene's camera distance, looking where it
# looks: the cameras in front, the render behind them ('View from the test camera' goes to the camera itself).
START_BACK = .4


class ViewerError(ValueError):
  """viser missing, or an address the viewer cannot listen on; the message says which and what to do."""


def require_viser():
  """The viser module; ViewerError saying how to install it when it is missing."""
  try:
    import viser  # pylint: disable=import-outside-toplevel  (an optional extra, needed by this tool only)
  except ImportError as err:
    raise ViewerError(f'tools.view needs viser (a web viewer, pure Python with its browser client): {INSTALL}') from err
  return viser


def check_address(host: str, port: int) -> None:
  """ViewerError naming --port when another program listens on it, naming --host when this machine has no such
  address (viser would quietly move to the next free port, or wait forever)."""
  try:
    family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
    with socket.socket(family, socket.SOCK_STREAM) as probe:
      probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # As the server binds: a closed port is free.
      probe.bind((host, port))
  except OSError as err:
    if err.errno == errno.EADDRINUSE:
      raise ViewerError(f'--port {port}: another program listens on it at {host}; choose a free one with '
                        '--port') from err
    raise ViewerError(f'--host {host!r} --port {port}: cannot listen there ({err.strerror or err}); expected an '
                      'address of this machine (127.0.0.1: this machine only, 0.0.0.0: every network) and a port '
                      'from 1 to 65535') from err


def start_server(host: str, port: int):
  """A viser server listening on host:port, its own printing silenced: the tool prints its address, and Ctrl-C's
  line stays the only one (viser's banner, its 'Server stopped' and asyncio's notes on its tasks at exit)."""
  viser = require_viser()
  import rich  # pylint: disable=import-outside-toplevel  (viser's printer, installed with it)
  check_address(host, port)
  rich.get_console().quiet = True
  logging.getLogger('asyncio').setLevel(logging.CRITICAL)
  server = viser.ViserServer(host=host, port=port, label=LABEL, verbose=False)
  if server.get_port() != port:  # Taken between the check and the bind: viser moved to another port.
    server.stop()
    raise ViewerError(f'--port {port}: another program listens on it at {host}; choose a free one with --port')
  return server


def view_of(camera) -> frames.View:
  """The frames.View of a viser camera handle."""
  return frames.View(tuple(camera.wxyz), tuple(camera.position), float(camera.fov), float(camera.aspect))


class Viewer:
  """A running viewer of runs (runs[0], and runs[1] to compare) at host:port; stop() ends it."""

  def __init__(self, runs: list, host: str, port: int, points, full_rows: int, interval: float):
    self.runs = runs
    self.server = start_server(host, port)
    self.server.scene.set_up_direction(tuple(scene.up_direction(runs[0])))
    self.groups = scene.draw(self.server, runs, points)
    self.clients = {}
    self.watcher = watch.CheckpointWatcher(runs, interval, self._reloaded, lambda text: self.panel.show_error(text))
    actions = {'change': self.refresh, 'reload': self.watcher.check, 'test_view': self.show_test_view,
               'interval': self.watcher.set_interval}
    self.panel = panel_lib.Panel(self.server, runs, full_rows, interval, self.groups, actions)
    self.server.on_client_connect(self._connect)
    self.server.on_client_disconnect(self._disconnect)

  def _connect(self, client) -> None:
    view = service.ClientView(self.runs, self.panel.options, self._sender(client), self.panel.frame_line(client))
    self.clients[client.client_id] = view
    self._move_camera(client, 0, START_BACK)
    client.camera.on_update(lambda camera: view.request(view_of(camera)))
    view.request(view_of(client.camera))

  def _disconnect(self, client) -> None:
    view = self.clients.pop(client.client_id, None)
    if view is not None:
      view.stop()

  @staticmethod
  def _sender(client):
    """send(image, format) showing a frame in client's browser."""
    def send(image, image_format: str) -> None:
      client.scene.set_background_image(image, format=image_format, jpeg_quality=service.JPEG_QUALITY)
    return send

  def _move_camera(self, client, k: int, back: float = 0.) -> None:
    """Puts client's camera at test camera k of the first run (moved back along its axis by back x the scene's
    camera distance), looking at the middle of the scene."""
    test = self.runs[0].test_cameras()
    c2w, distance = test.camtoworlds[k], scene.scene_distance(self.runs[0])
    client.camera.fov = cameras.field_of_view(test.pixtocams[k], test.size[0])
    client.camera.up_direction = -c2w[:, 1]
    client.camera.position = c2w[:, 3] - back * distance * c2w[:, 2]
    client.camera.look_at = c2w[:, 3] + c2w[:, 2] * distance

  def show_test_view(self, k: int) -> None:
    """Moves every browser's camera to test camera k and renders from there."""
    for client_id, view in list(self.clients.items()):
      client = self.server.get_clients().get(client_id)
      if client is not None:
        self._move_camera(client, k)
        view.request(view_of(client.camera))

  def refresh(self) -> None:
    """Renders every browser's frame again (a setting changed)."""
    for view in list(self.clients.values()):
      view.request()

  def _reloaded(self, runs: list) -> None:
    """After newer checkpoints: the panel's steps, the refined cameras, every frame."""
    self.panel.show_runs()
    if self.runs[0] in runs and 'refined' in self.runs[0].training_cameras():
      scene.move_frustums(self.groups['training cameras'], self.runs[0].training_cameras()['refined'])
    self.refresh()

  def stop(self) -> None:
    self.watcher.stop()
    for view in list(self.clients.values()):
      view.stop()
    self.server.stop()

