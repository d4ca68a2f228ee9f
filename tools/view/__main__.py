"""See a trained run from any viewpoint: a web viewer that renders on demand, compares two runs and watches training.

  python -m tools.view --gin_configs=configs/demo.gin --gin_bindings="Config.checkpoint_dir = 'out/mesh_demo/freenerf'"
                       [--compare_configs FILE ...] [--compare_bindings BINDING ...] [--points PLY]
                       [--height ROWS] [--check_every 10] [--port 8080] [--host 127.0.0.1]

Pass the gin configs and bindings used for training, as to eval.py (none: the demo's FreeNeRF). Serves a page
(viser: its browser client comes with the package, nothing is fetched from the network) at http://127.0.0.1:8080
and prints the address; Ctrl-C stops it. The page shows the training cameras as frustums with their photos, the
test cameras in blue, the render path, points (--points: a cloud tools.points wrote; a capture's own
structure-from-motion points without it) and, behind them, the run rendered from the browser's camera: colour,
depth or accumulation, small while the camera moves (the largest size that renders within 0.2 s, or a chosen
fraction) and at the full size (--height rows; default the test views') once it rests; the panel gives the step
and the seconds the last frame took. A browser starts a little behind the first test camera, looking where it looks
('View from the test camera' goes to it). With camera refinement the given cameras show in red beside the refined
ones.

--compare_configs / --compare_bindings: a second run of the same scene (default configs: the first run's; the first
run's bindings are not carried over) rendered from the same camera, split at a slider or side by side (each the
centre half of the view). The viewer loads newer checkpoints as train.py writes them, every --check_every seconds
and when asked in the panel. --host 0.0.0.0 serves every network interface: anyone who can reach this machine can
then view the runs and their photos. A missing run, a second run of another scene, a port in use: one line
`error: ...` (status 2).
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import socket
import sys
import time

from internal import cli
from internal import environment
from tools.view import app, runs as runs_lib, scene, watch

DEFAULT_PORT = 8080
LOCAL_HOST = '127.0.0.1'
WAKE_SECONDS = .5  # How soon Ctrl-C stops the viewer when the signal lands on another thread.


COMPARE_FLAGS = ('--compare_configs', '--compare_bindings')  # Multi-value flags, as the gin flags.


def parse_args(argv):
  parser = cli.flag_parser(__doc__.split('\n')[0], COMPARE_FLAGS)
  parser.add_argument('--compare_configs', action='extend', nargs='+', default=[], metavar='FILE',
                      help="the second run's gin configs (default: the first run's)")
  parser.add_argument('--compare_bindings', action='extend', nargs='+', default=[], metavar='BINDING',
                      help="the second run's gin bindings")
  parser.add_argument('--points', help='a point cloud PLY to show (tools.points writes them)')
  parser.add_argument('--height', type=int, help="rows of a full-size frame (default: the test views' height)")
  parser.add_argument('--check_every', type=float, default=watch.DEFAULT_INTERVAL,
                      help='seconds between looks for newer checkpoints (default 10; 0: only when asked)')
  parser.add_argument('--port', type=int, default=DEFAULT_PORT, help=f'the port to serve on (default {DEFAULT_PORT})')
  parser.add_argument('--host', default=LOCAL_HOST, help='the address to listen on (default 127.0.0.1: this machine '
                                                         'only; 0.0.0.0: every network this machine is on)')
  args = parser.parse_args(argv)
  if args.height is not None and args.height < 1 or args.check_every < 0:
    raise ValueError(f'--height {args.height} and --check_every {args.check_every}: expected >= 1 and >= 0')
  return args


def load_runs(args) -> list:
  """[the run] or [the run, the run to compare it with] of the flags."""
  runs = [runs_lib.load(args.gin_configs, args.gin_bindings)]
  if args.compare_configs or args.compare_bindings:
    runs.append(runs_lib.load(args.compare_configs or args.gin_configs, args.compare_bindings))
    runs_lib.check_same_scene(*runs)
  return runs


def address(host: str, port: int) -> str:
  """The page's address and who can reach it, in words."""
  if host in ('0.0.0.0', '::', ''):
    return (f'http://{socket.gethostname()}:{port} (listening on every network interface: anyone who can reach this '
            'machine can view the runs)')
  reach = 'this machine only' if host in (LOCAL_HOST, 'localhost', '::1') else f'whoever can reach {host}'
  return f'http://{host}:{port} ({reach})'


def serve(argv=None):
  """(app.Viewer, its runs) started from the flags argv."""
  args = parse_args(sys.argv[1:] if argv is None else argv)
  app.require_viser()
  app.check_address(args.host, args.port)  # Before the runs load (seconds); the server checks it again.
  runs = load_runs(args)
  points = scene.read_points(args.points, runs[0])
  rows = args.height or runs[0].test_set.height
  return app.Viewer(runs, args.host, args.port, points, rows, args.check_every), args


def main(argv=None) -> int:
  """CLI entry point: serves until Ctrl-C (status 130, as cli.run reports it)."""
  environment.report_startup()
  viewer, args = serve(argv)
  names = ' against '.join(f'{run.config.expname} (step {run.step})' for run in viewer.runs)
  print(f'viewing {names} at {address(args.host, args.port)}; Ctrl-C stops', flush=True)
  try:
    wait_for_ctrl_c()
  finally:
    viewer.stop()
  return 0


def wait_for_ctrl_c() -> None:
  """Sleeps until a KeyboardInterrupt, waking every WAKE_SECONDS: a SIGINT that the kernel hands to another of the
  process's threads (the server's, XLA's) only marks itself pending, and a main thread blocked without a timeout
  (threading.Event().wait()) never ran its handler."""
  while True:
    time.sleep(WAKE_SECONDS)


if __name__ == '__main__':
  sys.exit(cli.run(main))
