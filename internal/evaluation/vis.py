"""Visualisation: turbo-coloured depth, grey opacity and PNG saving as released (truncation, not rounding)."""

import io
import os

import matplotlib
import matplotlib.figure
import numpy as np
from PIL import Image

DEPTH_PERCENTILES = (0.5, 99.5)


def to_uint8(image) -> np.ndarray:
  """[H, W, C] or [H, W] floats in [0, 1] -> uint8 by clip(nan_to_num(x), 0, 1) * 255, truncated."""
  return (np.clip(np.nan_to_num(np.asarray(image, np.float64)), 0., 1.) * 255.).astype(np.uint8)


def save_png(image, path: str) -> None:
  """Writes a float [H, W, 3] or [H, W] image in [0, 1] to path as an 8-bit PNG."""
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  Image.fromarray(to_uint8(image)).save(path, format='PNG')


def save_picture(image, path: str) -> None:
  """Writes a picture meant for reading (a labelled grid of renders, a plot: float [H, W, 3] in [0, 1] or uint8) as
  a 256-colour PNG, about a quarter of a full-colour one's bytes: exact where it has no more colours, else with white
  and black kept exact (the page, the text)."""
  pixels = np.asarray(image) if np.asarray(image).dtype == np.uint8 else to_uint8(image)
  pixels = np.broadcast_to(pixels[..., None], pixels.shape + (3,)) if pixels.ndim == 2 else pixels[..., :3]
  colours, index = np.unique(pixels.reshape(-1, 3), axis=0, return_inverse=True)
  if len(colours) <= 256:
    picture = Image.fromarray(index.reshape(pixels.shape[:2]).astype(np.uint8), 'P')
    palette = colours
  else:
    picture = Image.fromarray(np.ascontiguousarray(pixels)).quantize(colors=256, method=Image.Quantize.FASTOCTREE)
    palette = np.asarray(picture.getpalette()[:768]).reshape(-1, 3)
    palette[(palette >= 248).all(1)], palette[(palette <= 7).all(1)] = 255, 0
  picture.putpalette(np.asarray(palette, np.uint8).ravel().tolist())
  os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
  picture.save(path, format='PNG', optimize=True)


def depth_range(depth) -> tuple:
  """(lo, hi) of -log(depth [...]) at the 0.5 / 99.5 percentiles over its finite positive values."""
  values = np.asarray(depth, np.float64)
  values = values[np.isfinite(values) & (values > 0)]
  if values.size == 0:
    return 0., 1.
  lo, hi = np.percentile(-np.log(values), DEPTH_PERCENTILES)
  return float(lo), float(max(hi, lo + 1e-6))


def colorize_depth(depth, value_range=None) -> np.ndarray:
  """Depth [H, W] -> turbo RGB [H, W, 3] in [0, 1] of -log(depth) normalized to value_range (lo, hi).

  value_range None uses depth_range(depth); near is red, far is blue. Non-positive depth maps to far.
  """
  lo, hi = depth_range(depth) if value_range is None else value_range
  depth = np.asarray(depth, np.float64)
  with np.errstate(divide='ignore', invalid='ignore'):
    neg_log = -np.log(np.where(depth > 0, depth, np.inf))
  scaled = np.clip(np.nan_to_num((neg_log - lo) / (hi - lo), nan=0., neginf=0., posinf=1.), 0., 1.)
  return matplotlib.colormaps['turbo'](scaled)[..., :3]


def colorize_opacity(acc) -> np.ndarray:
  """Opacity [H, W] in [0, 1] -> grey RGB [H, W, 3]."""
  acc = np.asarray(acc, np.float64)
  return np.repeat(acc[..., None], 3, axis=-1)


def visualize(rendering, depth_value_range=None) -> dict:
  """Rendered outputs {'rgb','distance_mean','acc'} [H, W, ...] -> {'color','depth','opacity'} RGB images."""
  return {'color': np.asarray(rendering['rgb']),
          'depth': colorize_depth(rendering['distance_mean'], depth_value_range),
          'opacity': colorize_opacity(rendering['acc'])}


def line_figure(lines: dict, joined: bool = True) -> tuple:
  """(figure, axes) of 6.4 x 4.4 inches with one series per name of lines {name: [(x, y)]}, joined or dots."""
  fig = matplotlib.figure.Figure(figsize=(6.4, 4.4))
  ax = fig.subplots()
  for name, points in lines.items():
    ax.plot(*zip(*points), marker='o', linestyle='-' if joined else 'none', label=name)
  return fig, ax


def save_figure(fig, ax, x_label: str, y_label: str, title: str, path: str) -> None:
  """Labels the axes, adds a grid and the legend (if anything is labelled) and writes the figure to path at 100 dpi
  (save_picture)."""
  ax.set_xlabel(x_label)
  ax.set_ylabel(y_label)
  ax.set_title(title)
  ax.grid(alpha=.3)
  if ax.get_legend_handles_labels()[0]:
    ax.legend(fontsize=7)
  fig.tight_layout()
  drawn = io.BytesIO()
  fig.savefig(drawn, dpi=100, format='png')
  save_picture(np.asarray(Image.open(drawn).convert('RGB')), path)
