"""Everything a GPU window needs, prepared on a CPU machine in one command, and the device call to make.

Usage: python -m bench.prepare_lease [--data_root ../shared/data] [--ledger bench/ledger.toml] [--offline]

1. Each pack of the ledger ([pack.*] of bench/ledger.toml) into .devdata/PACK.npz by tools.pack_scene from
   <data_root>/<its data folder> (a pack already there is kept: tools.pack_scene never replaces a file). When
   tools.pack_scene fails, its one line says why and this command exits with its status (2; 4: the disk is full).
2. The wheels the GPU image lacks (WHEELS, at constraints.txt's versions: pure-Python wheels that install on its
   Python 3.12) into .whl/ by `pip download` (kept when there; --offline downloads nothing).
3. What travels to the GPU machine counted against its 64 MiB: the files git tracks or does not ignore, and the
   carried folders (.whl, .devdata: both in .gitignore).
4. The device tool's call, printed: `bash bench/lease.sh` with the carry list and its time limit (TIMEOUT_S: the
   lease's BUDGET and a minute to spare).
"""

import argparse
import os
import re
import subprocess
import sys

from bench import ledger as ledger_lib
from internal import cli

WHEELS = ('gin-config', 'pypng', 'tensorboardX')  # Not in the GPU image (docs/benchmarks.md); protobuf and numpy are.
CARRY = ('.whl', ledger_lib.DATA)
TRAVEL_LIMIT = 64 * 2**20  # The device tool's limit on what travels.
# The call's limit: bench/lease.sh ends within its BUDGET, 530 s by default, a minute less (docs/benchmarks.md).
TIMEOUT_S = 590


def pinned(name: str, constraints: str = os.path.join(ledger_lib.ROOT, 'constraints.txt')) -> str:
  """'name==version' as constraints.txt pins it; ValueError when it does not."""
  with open(constraints) as f:
    for line in f:
      if re.fullmatch(rf'{re.escape(name)}==\S+', line.strip(), re.IGNORECASE):
        return line.strip()
  raise ValueError(f'{constraints!r} pins no version of {name}; expected a line {name}==VERSION')


def make_packs(ledger: ledger_lib.Ledger, data_root: str, data: str) -> int:
  """Each pack of the ledger into data/PACK.npz (tools.pack_scene), unless it is there; returns 0, or the status
  of the tools.pack_scene that failed (its one line, naming the pack, printed)."""
  os.makedirs(data, exist_ok=True)
  for name, spec in ledger.packs.items():
    out = os.path.join(data, f'{name}.npz')
    if os.path.isfile(out):
      print(f'{out}: there, kept')
      continue
    source = os.path.join(data_root, spec['data'])
    status = subprocess.run([sys.executable, '-m', 'tools.pack_scene', f"--gin_configs={spec['gin']}",
                             '--gin_bindings', f"Config.data_dir = '{source}'", *spec['bindings'], '--out', out],
                            check=False, cwd=ledger_lib.ROOT).returncode
    if status:
      return status
  return 0


def download_wheels(folder: str) -> None:
  """The WHEELS for Python 3.12 into folder (pip download, wheels only, no dependencies), unless there."""
  os.makedirs(folder, exist_ok=True)
  have = {re.split(r'-\d', name)[0].lower().replace('_', '-') for name in os.listdir(folder)}
  wanted = [pinned(name) for name in WHEELS if name.lower() not in have]
  if wanted:
    subprocess.run([sys.executable, '-m', 'pip', 'download', '--no-deps', '--only-binary=:all:', '--python-version',
                    '3.12', '-d', folder, *wanted], check=True)


def _size(path: str) -> int:
  """Bytes of a file, or of every file under a folder."""
  if os.path.isfile(path):
    return os.path.getsize(path)
  return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files)


def travelling(root: str = ledger_lib.ROOT) -> dict:
  """{'tree': bytes of the files git tracks or does not ignore, carried folder: bytes}."""
  listed = subprocess.run(['git', '-C', root, 'ls-files', '-z', '--cached', '--others', '--exclude-standard'],
                          capture_output=True, check=True).stdout.decode().split('\0')
  sizes = {'tree': sum(_size(os.path.join(root, p)) for p in listed if p and os.path.isfile(os.path.join(root, p)))}
  sizes.update({folder: _size(os.path.join(root, folder)) for folder in CARRY})
  return sizes


def device_call() -> str:
  """The device tool's run call that moves the ledger forward."""
  return f'run(command="bash bench/lease.sh", carry={list(CARRY)}, timeout_s={TIMEOUT_S})'


def main(argv=None) -> int:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--data_root', default=os.path.join('..', 'shared', 'data'))
  parser.add_argument('--ledger', default=ledger_lib.LEDGER)
  parser.add_argument('--offline', action='store_true', help='download no wheels (count what is there)')
  args = parser.parse_args(argv)
  ledger = ledger_lib.load(args.ledger)
  status = make_packs(ledger, args.data_root, os.path.join(ledger_lib.ROOT, ledger_lib.DATA))
  if status:
    return status
  if not args.offline:
    download_wheels(os.path.join(ledger_lib.ROOT, '.whl'))
  sizes = travelling()
  total = sum(sizes.values())
  print('travels: ' + ', '.join(f'{name} {size / 2**20:.2f} MiB' for name, size in sizes.items())
        + f'; {total / 2**20:.2f} of {TRAVEL_LIMIT / 2**20:.0f} MiB')
  if total > TRAVEL_LIMIT:
    raise ValueError(f'{total / 2**20:.2f} MiB would travel, over the device tool\'s {TRAVEL_LIMIT / 2**20:.0f} MiB; '
                     'commit fewer large files or carry less')
  print(f'The GPU window\'s one call (device tool), then `python -m bench.ledger unpack FILES_AT`:\n{device_call()}')
  return 0


if __name__ == '__main__':
  sys.exit(cli.run(main))
