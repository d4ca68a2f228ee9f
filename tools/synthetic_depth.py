"""Depth maps of the generated scene's training views as a monocular model would give them, for Config.depth_prior_dir.

  python -m tools.synthetic_depth --gin_configs=configs/demo.gin --out DIR [--gamma 0.8] [--blur 1] [--noise 0.02]

The project ships no depth model and downloads none (docs/running.md says how to write maps with DPT, MiDaS or
Depth Anything). This tool stands in for one on the generated scene, whose exact depths it distorts the way those
models err: the exact disparity normalized to [0, 1], raised to --gamma (a monotone bend), blurred across edges
by a Gaussian of --blur pixels, plus Gaussian noise of --noise (of the range), then mapped by a random scale and
shift (--seed). It writes <image stem>.npy (float32 disparity; 0 where the ray hits nothing) for each training
view of the run's flags, and a PNG of them side by side with the exact depths (--picture). An existing --out
folder holding files is refused, so no map is replaced; so is a flag out of its range, in one line naming it.
"""

import math
import os
import sys

import matplotlib.figure
import numpy as np
from scipy import ndimage

from internal import cli
from internal import config_loader
from internal.datasets import load_dataset
from internal.evaluation import vis


def monocular_like(depth: np.ndarray, rng: np.random.Generator, gamma: float, blur: float,
                   noise: float) -> np.ndarray:
  """Disparity-like f32 [H, W] of an exact depth [H, W] (0 = no hit, kept 0): normalized, bent, blurred, noisy,
  then scaled and shifted at random."""
  valid = depth > 0
  disparity = np.where(valid, 1. / np.where(valid, depth, 1.), 0.)
  low, high = disparity[valid].min(), disparity[valid].max()
  bent = np.where(valid, np.clip((disparity - low) / max(high - low, 1e-12), 0., 1.)**gamma, 0.)
  if blur > 0:  # Over the valid pixels only, as a model smooths the object's edge into its neighbours.
    weight = ndimage.gaussian_filter(valid.astype(np.float64), blur)
    bent = np.where(valid, ndimage.gaussian_filter(bent, blur) / np.maximum(weight, 1e-12), 0.)
  bent = bent + noise * rng.normal(size=bent.shape)
  scale, shift = rng.uniform(.5, 20.), rng.uniform(.1, 5.)
  return np.where(valid, scale * bent + shift, 0.).astype(np.float32)


def save_picture(path: str, exact: np.ndarray, maps: np.ndarray) -> None:
  """A PNG of each view's exact depth (top) above its map (bottom), both coloured near red, far blue."""
  fig = matplotlib.figure.Figure(figsize=(2.2 * len(maps), 4))
  for i, (depth, prior) in enumerate(zip(exact, maps)):
    inverse = np.where(prior > 0, 1. / np.where(prior > 0, prior, 1.), 0.)  # Disparity-like: 1 / map is depth-like.
    for row, (image, title) in enumerate(((depth, 'exact depth'), (inverse, 'prior (as 1 / map)'))):
      ax = fig.add_subplot(2, len(maps), row * len(maps) + i + 1)
      ax.imshow(vis.colorize_depth(image))
      ax.set_title(title, fontsize=8)
      ax.set_axis_off()
  fig.tight_layout()
  fig.savefig(path, dpi=100)


def check_flags(args) -> None:
  """ValueError naming the first of --gamma, --blur, --noise, --seed out of its range."""
  for flag, value, inside, expected in (('--gamma', args.gamma, args.gamma > 0, '> 0'),
                                        ('--blur', args.blur, args.blur >= 0, '>= 0 (pixels)'),
                                        ('--noise', args.noise, args.noise >= 0, '>= 0 (of the range)')):
    if not (inside and math.isfinite(value)):
      raise ValueError(f'{flag} {value}: expected a finite number {expected}')
  expected = config_loader.seed_expected(args.seed)
  if expected:
    raise ValueError(f'--seed {args.seed}: expected {expected}')


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  parser = cli.flag_parser(__doc__.splitlines()[0])
  parser.add_argument('--out', required=True, help='the folder to write the maps to (new or empty)')
  parser.add_argument('--gamma', type=float, default=.8, help='exponent on the normalized disparity (default 0.8)')
  parser.add_argument('--blur', type=float, default=1., help='Gaussian blur, pixels (default 1)')
  parser.add_argument('--noise', type=float, default=.02, help='Gaussian noise, of the range (default 0.02)')
  parser.add_argument('--seed', type=int, default=0, help='seed of the noise, scale and shift (default 0)')
  parser.add_argument('--picture', help='also a PNG of the exact depths above the maps')
  args = parser.parse_args(argv)
  check_flags(args)
  if os.path.isdir(args.out) and os.listdir(args.out):
    raise FileExistsError(f'--out {args.out!r} holds files already; choose a new or empty folder')
  config = cli.config_from_flags(args)
  if config.dataset_loader != 'generated':
    raise ValueError(f"Config.dataset_loader = {config.dataset_loader!r}: only the generated scene ('generated') "
                     'has the exact depths this tool distorts')
  data = load_dataset('train', config, ground_truth=True)
  rng = np.random.default_rng(args.seed)
  if args.blur > max(data.height, data.width):  # A wider blur is flat over the image, and costs memory.
    raise ValueError(f'--blur {args.blur}: expected at most the images\' longer side, {max(data.height, data.width)} '
                     'pixels')
  with np.errstate(over='ignore'):  # An overflow is one error below, naming --noise.
    maps = np.stack([monocular_like(depth, rng, args.gamma, args.blur, args.noise) for depth in data.depths])
  if not np.isfinite(maps).all():
    raise ValueError(f'--noise {args.noise}: the maps overflow float32; expected a smaller noise (of the range)')
  os.makedirs(args.out, exist_ok=True)
  for path, values in zip(data.image_paths, maps):
    np.save(os.path.join(args.out, os.path.splitext(os.path.basename(path))[0] + '.npy'), values)
  if args.picture:
    save_picture(args.picture, data.depths, maps)
  print(f'{len(maps)} disparity-like maps of {data.name} in {args.out!r}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
