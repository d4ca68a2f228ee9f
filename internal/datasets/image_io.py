"""Image reading and integer-factor downsampling ('released' bilinear quirk and true 'area' block mean)."""

import numpy as np
from PIL import Image
import png  # pypng: decodes 16-bit PNGs at their full depth, which Pillow reads at 8 bits for RGB(A).

from internal.datasets.base import DatasetError, check_choice, require_file

DOWNSAMPLE_MODES = ('released', 'area')


# 16-bit PNGs: Image.convert would clip a grey one at 255 (an image trained saturated) and Pillow opens RGB(A)
# ones at 8 bits, so they are decoded with pypng and scaled by their own maximum, 65535.
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'
LUMA = np.array([0.299, 0.587, 0.114], np.float32)  # Pillow's RGB -> L weights.


def _png_bit_depth(path: str) -> int:
  """The bit depth of a PNG file from its IHDR chunk; 8 for other files."""
  with open(path, 'rb') as f:
    head = f.read(25)
  return head[24] if head[:8] == PNG_SIGNATURE and len(head) == 25 else 8


def _to_mode(pixels: np.ndarray, mode: str) -> np.ndarray:
  """f32 [H,W,C] grey (C 1-2) or colour (C 3-4, alpha last) -> [H,W,C'] of mode 'L', 'RGB' or 'RGBA'."""
  colour = pixels[..., :3] if pixels.shape[-1] >= 3 else np.repeat(pixels[..., :1], 3, -1)
  alpha = pixels[..., -1:] if pixels.shape[-1] in (2, 4) else np.ones_like(pixels[..., :1])
  if mode == 'L':
    return (colour @ LUMA)[..., None] if pixels.shape[-1] >= 3 else pixels[..., :1]
  return colour if mode == 'RGB' else np.concatenate([colour, alpha], -1)


def _read_png16(path: str, mode: str) -> np.ndarray:
  """A 16-bit PNG as f32 [H,W,C] of mode, values / 65535."""
  width, height, rows, info = png.Reader(filename=path).asDirect()
  pixels = np.vstack([np.asarray(row, np.float32) for row in rows]) / (2.**info['bitdepth'] - 1.)
  return _to_mode(pixels.reshape(height, width, info['planes']), mode)


def read_image(path: str, mode: str = 'RGB') -> np.ndarray:
  """An image file as f32 [H,W,C] in [0,1], scaled by its own depth (C: 1 'L', 3 'RGB', 4 'RGBA'); names it if bad."""
  require_file(path, 'image')
  try:
    if _png_bit_depth(path) == 16:
      return _read_png16(path, mode)
    with Image.open(path) as image:
      return np.asarray(image.convert(mode)).reshape(image.height, image.width, -1).astype(np.float32) / 255.
  except (OSError, SyntaxError, ValueError, png.Error) as err:
    raise DatasetError(f'cannot read image {path!r} (expected a complete PNG/JPEG file): {err}') from err


def image_size(path: str) -> tuple:
  """(height, width) of an image file, from its header only."""
  require_file(path, 'image')
  try:
    with Image.open(path) as image:
      return image.height, image.width
  except (OSError, SyntaxError, ValueError) as err:
    raise DatasetError(f'cannot read image {path!r} (expected a PNG/JPEG file): {err}') from err


def linear_taps(src: int, dst: int) -> tuple:
  """cv2 INTER_LINEAR taps for resizing src -> dst samples: (i0 [dst], i1 [dst], w1 [dst] f32)."""
  pos = ((np.arange(dst) + 0.5) * (1. / (dst / src)) - 0.5).astype(np.float32)
  i0 = np.floor(pos).astype(np.int64)
  w1 = pos - i0.astype(np.float32)
  low, high = i0 < 0, i0 >= src - 1
  i0 = np.clip(i0, 0, src - 1)
  w1[low | high] = 0.
  return i0, np.minimum(i0 + 1, src - 1), w1


def resize_linear_axis(img: np.ndarray, dst: int, axis: int) -> np.ndarray:
  """Bilinear (cv2 INTER_LINEAR) resampling of one axis of img to dst samples."""
  i0, i1, w1 = linear_taps(img.shape[axis], dst)
  shape = [1] * img.ndim
  shape[axis] = dst
  w1 = w1.reshape(shape)
  return np.take(img, i0, axis=axis) * (1. - w1) + np.take(img, i1, axis=axis) * w1


def downsample_released(img: np.ndarray, factor: int) -> np.ndarray:
  """[H,W,C] -> [H//f,W//f,C]: what the released cv2.resize call computes (INTER_LINEAR, sample (x+.5)f-.5)."""
  out = resize_linear_axis(img.astype(np.float32), img.shape[0] // factor, 0)
  return resize_linear_axis(out, img.shape[1] // factor, 1).astype(np.float32)


def downsample_area(img: np.ndarray, factor: int) -> np.ndarray:
  """[H,W,C] -> [H//f,W//f,C] block mean; H and W must be multiples of factor."""
  h, w = img.shape[:2]
  if h % factor or w % factor:
    raise DatasetError(f"Config.downsample_mode = 'area' needs image sides divisible by the factor {factor}; "
                       f'got {h}x{w}')
  total = sum(img[i::factor, j::factor].astype(np.float64) for i in range(factor) for j in range(factor))
  return (total / factor ** 2).astype(np.float32)


def crop_to_blocks(img: np.ndarray, factor: int) -> np.ndarray:
  """[H,W,C] -> [H - H % f, W - W % f, C]: the last rows and columns, which fill no f x f block, left out."""
  return img[:img.shape[0] - img.shape[0] % factor, :img.shape[1] - img.shape[1] % factor]


def downsample(img: np.ndarray, factor: int, mode: str) -> np.ndarray:
  """[H,W,C] f32 -> [H//f,W//f,C] f32 with mode 'released' or 'area'; factor 1 returns img as float32."""
  check_choice('Config.downsample_mode', mode, DOWNSAMPLE_MODES)
  if factor <= 1:
    return img.astype(np.float32)
  fn = downsample_released if mode == 'released' else downsample_area
  return fn(img, factor)


def load_rgb(path: str, factor: int, mode: str) -> np.ndarray:
  """Reads an RGB image as f32 [H//f,W//f,3] in [0,1], downsampled right after decoding."""
  return downsample(read_image(path, 'RGB'), factor, mode)


def load_rgba(path: str, factor: int, mode: str) -> np.ndarray:
  """Reads an image as f32 RGBA [H//f,W//f,4] in [0,1] (opaque alpha when the file has none)."""
  return downsample(read_image(path, 'RGBA'), factor, mode)


def load_binary_mask(path: str, factor: int, mode: str) -> np.ndarray:
  """Released mask rule: RGB/255 == 1 per channel -> f32 {0,1} [H,W,3], then downsampled (3-channel float)."""
  return downsample((read_image(path, 'RGB') == 1.).astype(np.float32), factor, mode)


def load_stack(paths, load_fn) -> np.ndarray:
  """[N,...] stack of load_fn(path) over paths; an image whose size differs from the first raises naming both."""
  images = []
  for path in paths:
    image = load_fn(path)
    if images and image.shape[:2] != images[0].shape[:2]:
      raise DatasetError(f'image {path!r} is {image.shape[0]}x{image.shape[1]} after loading; expected '
                         f'{images[0].shape[0]}x{images[0].shape[1]} like {paths[0]!r} (every image of a split '
                         'must have the same size)')
    images.append(image)
  return np.stack(images)


def write_png(path: str, img: np.ndarray) -> None:
  """Writes f32 [H,W,C] in [0,1] (C in 1,3,4) or uint8 as an 8-bit PNG."""
  if img.dtype != np.uint8:
    img = np.round(np.clip(img, 0., 1.) * 255.).astype(np.uint8)
  Image.fromarray(img[..., 0] if img.shape[-1] == 1 else img).save(path)
