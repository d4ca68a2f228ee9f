"""Packs one scene (both splits, cameras, DTU masks, render-path cameras) into a single compressed .npz.

Usage: python -m tools.pack_scene --gin_configs=configs/freenerf/dtu3_freenerf.gin \\
         --gin_bindings="Config.data_dir = '/data/dtu'" "Config.dtu_scan = 'scan24'" --out scan24.npz

The flags are those of train.py; the scene is loaded with them, packed, read back and compared with what
the loader returned (rays bitwise, images/masks exactly) before the file is kept. Train or evaluate on it
with Config.dataset_loader = 'packed' and Config.data_dir = '<file>.npz'; the settings that shaped the data
(factor, n_input_views, split settings, ...) must stay as they were. See internal/datasets/packed.py.
"""

from internal import interrupt
interrupt.one_line_when_run(__name__)  # Before the other imports: Ctrl-C while they load (seconds) is one line.

import dataclasses
import errno
import os
import sys

from internal.datasets import base, load_dataset, loader, packed
from internal import cli


def pack(config, out: str) -> dict:
  """Writes the pack of Config's scene to out after checking it loads back equal; returns {split: Dataset}."""
  datasets = {split: load_dataset(split, config, ground_truth=True) for split in base.SPLITS}
  try:
    packed.write_pack(out, loader.pack_arrays(config, datasets))
  except OSError as err:
    if err.errno == errno.ENOSPC:  # cli.run's one line names the file; exit status 4.
      raise OSError(err.errno, err.strerror, out) from err
    raise ValueError(f'--out {out!r} cannot be written ({err.strerror or err}); expected a writable folder') from err
  reloaded = dataclasses.replace(config, dataset_loader='packed', data_dir=out)
  for split, data in datasets.items():
    diff = packed.datasets_equal(packed.load_scene(split, reloaded), data)
    if diff:
      os.remove(out)
      raise RuntimeError(f'packed {split} split differs from the loaded one in {diff}; nothing written')
  return datasets


def main(argv=None) -> int:
  """CLI entry point; returns the exit status."""
  parser = cli.flag_parser(__doc__.splitlines()[0])
  parser.add_argument('--out', required=True, metavar='FILE.npz', help='the pack to write')
  args = parser.parse_args(argv)
  if not args.out.endswith('.npz'):
    raise ValueError(f'--out {args.out!r}: expected a file name ending in .npz')
  if os.path.exists(args.out):
    raise FileExistsError(f'--out {args.out!r} exists; delete it or choose another name (a pack never replaces a '
                          'file)')
  if not os.path.isdir(os.path.dirname(args.out) or '.'):
    raise FileNotFoundError(f'--out {args.out!r}: its folder {os.path.dirname(args.out)!r} does not exist; make it '
                            'first')
  config = cli.config_from_flags(args)
  datasets = pack(config, args.out)
  views = ', '.join(f'{split} {len(d.ids)} views {d.height}x{d.width}' for split, d in datasets.items())
  print(f'{args.out}: {os.path.getsize(args.out) / 2**20:.2f} MiB ({config.dataset_loader}, {views})')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
