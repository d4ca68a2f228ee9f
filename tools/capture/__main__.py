"""Photos or a video -> a capture folder to train on: structure-from-motion with pycolmap, checked and reported.

Usage: python -m tools.capture PHOTOS_DIR_OR_VIDEO --out CAPTURE_DIR [--photos NAME ...] [--max_size 800]
                               [--frames 100] [--matching sequential|exhaustive] [--camera shared|per_image]
                               [--camera_model SIMPLE_RADIAL] [--overwrite]

Writes CAPTURE_DIR/images/ (the photos upright, or the video's sharpest frames), sparse/0/ (the largest model, its
cameras at the full image size), images_2/, images_4/, images_8/, sfm/ (the structure-from-motion copies, database
and every model), report.json and cameras.png; loads the capture back through the capture loader, prints a summary
and the command to train on it. Needs pycolmap: pip install -r requirements-capture.txt.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import argparse
import sys

from internal import cli
from tools.capture import model, pipeline, report as report_lib, sfm


def parse_args(argv) -> pipeline.Options:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('input', help='a folder of JPEG/PNG photos, or a video file')
  parser.add_argument('--out', required=True, help='the capture folder to create')
  parser.add_argument('--photos', nargs='+', metavar='NAME', help='structure-from-motion on only these photos of '
                      'the folder (file names), e.g. the few you will train on; default: all of them')
  parser.add_argument('--max_size', type=int, default=pipeline.MAX_SIZE, help='long side in pixels of the copies '
                      'that structure-from-motion runs on (cameras are scaled back to the full images)')
  parser.add_argument('--frames', type=int, default=100, help='video: how many frames to take (the sharpest of '
                      'each of this many equal windows)')
  parser.add_argument('--matching', choices=sfm.MATCHING, help='which image pairs to match: sequential '
                      '(neighbours in name order; default for a video) or exhaustive (all pairs; default for photos)')
  parser.add_argument('--camera', choices=('shared', 'per_image'), default='shared', help='shared: one camera per '
                      'image size and EXIF camera (one phone); per_image: every image its own camera')
  parser.add_argument('--camera_model', choices=model.CAMERA_MODELS, default='SIMPLE_RADIAL',
                      help="COLMAP's camera model (the loader inverts the distortion of each)")
  parser.add_argument('--overwrite', action='store_true', help='replace what tools.capture wrote in --out before '
                      '(only that: anything else there stays, and is named if it is in the way)')
  return pipeline.Options(**vars(parser.parse_args(argv)))


def main(argv=None) -> int:
  report = pipeline.make(parse_args(argv), cli.command_line('tools.capture', argv))
  print(report_lib.summary(report))
  print(f'next: {report["next"]}\n      (then eval.py and render.py with the same flags)')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
