"""Renders the camera path of a scene (spiral for LLFF / DTU) with a run's newest checkpoint: frames and videos.

  python render.py --gin_configs=configs/freenerf/llff3_freenerf.gin --gin_bindings="Config.llff_scan = 'fern'"

Pass the gin configs and bindings used for training (none: the demo's FreeNeRF, configs/demo.gin then
configs/demo_forward.gin). Writes <Config.checkpoint_dir>/path_renders_step_<step>/{color,depth,opacity}_<frame>.png
(or into Config.output_dir, when set); depth is the turbo map of -log depth normalized by the 0.5 / 99.5
percentiles of frame 0. With imageio-ffmpeg installed it also writes <scene>_<expname>_{color,depth,opacity}.mp4
there. On a CPU use fewer frames and a lower resolution, e.g.
--gin_bindings="Config.render_path_frames = 30" "Config.render_factor = 8".
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import sys

from internal import cli
from internal.evaluation import render_path


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  args = cli.flag_parser(__doc__.split('\n')[0]).parse_args(argv)
  render_path.render(cli.config_from_flags(args))
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
