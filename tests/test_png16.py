"""16-bit PNGs (grey and RGBA) read at their full depth; a truncated one is named."""

import pathlib
import struct
import zlib

import numpy as np
import pytest

from internal.datasets import image_io


def _write_png16(path, values: np.ndarray) -> None:
  """Writes uint16 [H,W] (grey) or [H,W,4] (RGBA) as a 16-bit PNG, encoded here (Pillow writes no 16-bit RGBA)."""
  color_type = {2: 0, 3: 6}[values.ndim]
  height, width = values.shape[:2]
  raw = b''.join(b'\x00' + values[y].astype('>u2').tobytes() for y in range(height))  # Filter 0 per row.
  chunk = lambda kind, data: (struct.pack('>I', len(data)) + kind + data +
                              struct.pack('>I', zlib.crc32(kind + data) & 0xffffffff))
  header = struct.pack('>IIBBBBB', width, height, 16, color_type, 0, 0, 0)
  pathlib.Path(path).write_bytes(b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', header) + chunk(b'IDAT', zlib.compress(raw)) +
                                 chunk(b'IEND', b''))



def test_a_16_bit_grey_png_reads_at_its_full_depth(tmp_path):
  offsets = 100 * np.arange(1, 25)
  grey = (27 * 257 + np.concatenate([offsets, -offsets]).reshape(6, 8)).astype(np.uint16)  # Mean 27/255.
  _write_png16(tmp_path / 'grey.png', grey)
  expected = grey.astype(np.float64) / 65535.
  rgb = image_io.load_rgb(str(tmp_path / 'grey.png'), 1, 'released')
  assert rgb.shape == (6, 8, 3) and abs(rgb.mean() - 27 / 255) < 1e-6
  np.testing.assert_allclose(rgb, np.repeat(expected[..., None], 3, -1), atol=1e-6)
  rgba = image_io.load_rgba(str(tmp_path / 'grey.png'), 1, 'released')
  np.testing.assert_allclose(rgba[..., :3], rgb)
  np.testing.assert_array_equal(rgba[..., 3], 1.)



def test_a_16_bit_rgba_png_reads_at_its_full_depth(tmp_path):
  rgba = np.random.default_rng(1).integers(0, 65536, (6, 8, 4)).astype(np.uint16)
  _write_png16(tmp_path / 'rgba.png', rgba)
  read = image_io.read_image(str(tmp_path / 'rgba.png'), 'RGBA')
  np.testing.assert_allclose(read, rgba / 65535., atol=1e-7)  # Within float32 rounding, not 1/255.
  assert read.dtype == np.float32 and read.max() <= 1.
  np.testing.assert_allclose(image_io.read_image(str(tmp_path / 'rgba.png'), 'RGB'), rgba[..., :3] / 65535.,
                             atol=1e-7)
  luma = image_io.read_image(str(tmp_path / 'rgba.png'), 'L')[..., 0]
  np.testing.assert_allclose(luma, rgba[..., :3] @ [0.299, 0.587, 0.114] / 65535., atol=1e-6)



def test_a_truncated_16_bit_png_is_named(tmp_path):
  _write_png16(tmp_path / 'rgba.png', np.zeros((6, 8, 4), np.uint16))
  data = (tmp_path / 'rgba.png').read_bytes()
  (tmp_path / 'rgba.png').write_bytes(data[:60])
  with pytest.raises(image_io.DatasetError, match="cannot read image .*rgba.png"):
    image_io.read_image(str(tmp_path / 'rgba.png'))
