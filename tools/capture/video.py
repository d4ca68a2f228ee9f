"""Frames of a video for structure-from-motion: the sharpest frame of each of N equal windows of the video.

Decoded by the ffmpeg binary that the imageio-ffmpeg package ships (no system install), which also turns frames
upright by the video's rotation tag. Sharpness is the variance of the Laplacian of the frame's grey levels (on at
most SHARPNESS_WIDTH columns): motion blur and defocus lower it. The frames are written as images/frame_<k>.jpg,
k the frame's number in the video, so that the name order is the time order.
"""

import contextlib
import io
import os
from typing import Iterator, List, Tuple

import numpy as np
from PIL import Image

from tools.capture import CaptureError
from tools.capture.output import Output

SHARPNESS_WIDTH = 480
JPEG_QUALITY = 95


def sharpness(frame: np.ndarray) -> float:
  """Variance of the 4-neighbour Laplacian of frame [H, W, 3] (uint8) in grey, subsampled to SHARPNESS_WIDTH."""
  step = max(1, frame.shape[1] // SHARPNESS_WIDTH)
  grey = frame[::step, ::step].astype(np.float32).mean(-1)
  laplacian = (4. * grey[1:-1, 1:-1] - grey[:-2, 1:-1] - grey[2:, 1:-1] - grey[1:-1, :-2] - grey[1:-1, 2:])
  return float(laplacian.var())


def _decode_error(path: str, err: Exception) -> CaptureError:
  """The one-line error of a video ffmpeg cannot decode, with ffmpeg's last line."""
  last = str(err).strip().splitlines()[-1] if str(err).strip() else type(err).__name__
  return CaptureError(f'cannot decode the video {path!r} with ffmpeg (expected a video file such as .mp4 or .mov): '
                      f'{last}')


def _decoded(path: str) -> Tuple[int, Iterator[np.ndarray]]:
  """(frame count, the frames [H, W, 3] uint8 one by one) of the video at path; CaptureError if it cannot be read."""
  import imageio_ffmpeg  # pylint: disable=import-outside-toplevel  (a base requirement; only videos need it)
  try:
    with contextlib.redirect_stdout(io.StringIO()):  # Its note on a rotated frame size is not for our users.
      count = imageio_ffmpeg.count_frames_and_secs(path)[0]
      reader = imageio_ffmpeg.read_frames(path)
      width, height = next(reader)['size']
  except (RuntimeError, OSError, StopIteration, ValueError, KeyError) as err:
    raise _decode_error(path, err) from err
  if not count:
    raise CaptureError(f'the video {path!r} has no frames ffmpeg can decode')

  def frames():
    try:
      for data in reader:
        yield np.frombuffer(data, np.uint8).reshape(height, width, 3)
    except (RuntimeError, OSError, ValueError) as err:
      raise _decode_error(path, err) from err
  return count, frames()


def extract_frames(path: str, n_frames: int, output: Output) -> List[str]:
  """Writes the sharpest frame of each of n_frames equal windows of the video to images/; returns their names."""
  count, frames = _decoded(path)
  windows = min(n_frames, count)
  digits = max(5, len(str(count)))
  names, best = [], None  # best: (sharpness, frame, its index, its window) of the current window.
  for index, frame in enumerate(frames):
    window = min(index * windows // count, windows - 1)  # The count is ffmpeg's estimate: a longer video stays in.
    if best is not None and window != best[3]:
      names.append(_write(best, digits, output))
      best = None
    score = sharpness(frame)
    if best is None or score > best[0]:
      best = (score, frame.copy(), index, window)
  if best is not None:
    names.append(_write(best, digits, output))
  if not names:
    raise CaptureError(f'the video {path!r} has no frames ffmpeg can decode')
  return names


def _write(best: tuple, digits: int, output: Output) -> str:
  """Writes the frame of best = (sharpness, frame, index, window) as images/frame_<index>.jpg; returns the name."""
  name = f'frame_{best[2]:0{digits}d}.jpg'
  Image.fromarray(best[1]).save(output.claim(os.path.join('images', name)), quality=JPEG_QUALITY)
  return name
