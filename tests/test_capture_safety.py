"""tools.capture never removes or changes a photo and stops in one line: an input inside --out, its own outputs
beside the photos, a read-only or full --out, Ctrl-C while it imports or maps (then the same command finishes)."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys

import pytest

from internal import cli
from internal import interrupt
from test_capture import REPO, _photos, needs_cup, needs_pycolmap
from test_disk_full import small_disk  # pylint: disable=unused-import  (a fixture: a 32 MiB tmpfs)
from test_interrupts import SIGINT_AT_JAX_IMPORT
from test_read_only import read_only
from tools.capture import __main__ as capture, output

# The subprocesses are forked from this process, which runs jax: they exec at once.
pytestmark = [needs_cup, needs_pycolmap, pytest.mark.filterwarnings('ignore:os.fork:RuntimeWarning')]
pycolmap = pytest.importorskip('pycolmap')
PHOTOS = [f'{i}.jpg' for i in range(1, 9)]  # Eight neighbours along the cup's arc: a capture in seconds at MAX_SIZE
# (from six, structure-from-motion registered only two in one clean-clone run of the suite).
MAX_SIZE = '200'


def _snapshot(folder) -> dict:
  """{relative path: SHA-256} of every file under folder."""
  found = {}
  for parent, _, names in os.walk(folder):
    for name in names:
      with open(os.path.join(parent, name), 'rb') as f:
        found[os.path.relpath(os.path.join(parent, name), folder)] = hashlib.sha256(f.read()).hexdigest()
  return found


def _cli(monkeypatch, capsys, *argv) -> tuple:
  """(exit status, stderr, stdout) of `python -m tools.capture argv` run in this process."""
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  status = cli.run(lambda: capture.main([str(a) for a in argv]))
  printed = capsys.readouterr()
  return status, printed.err, printed.out


def _subprocess(*argv, env=None) -> subprocess.CompletedProcess:
  """`python -m tools.capture argv` in a process of its own."""
  env = dict(os.environ if env is None else env)
  env.pop(cli.DEBUG_ENV, None)
  return subprocess.run([sys.executable, '-m', 'tools.capture', *map(str, argv)], cwd=REPO, env=env,
                        capture_output=True, text=True, timeout=600, check=False)


@pytest.fixture(scope='module')
def made(tmp_path_factory):
  """(photo folder, a capture of it made by the tool)."""
  root = tmp_path_factory.mktemp('made')
  source = _photos(root / 'photos', PHOTOS)
  assert capture.main([source, '--out', str(root / 'capture'), '--max_size', MAX_SIZE]) == 0
  return root / 'photos', root / 'capture'


def test_an_input_inside_out_is_refused_before_anything_is_removed(made, monkeypatch, capsys):
  folder = made[1]
  before = _snapshot(folder)
  for source in (folder / 'images', folder):
    status, errout, _ = _cli(monkeypatch, capsys, source, '--out', folder, '--overwrite', '--max_size', MAX_SIZE)
    assert status == 2 and errout == (f'error: the input {str(source)!r} is inside --out {str(folder)!r}, where the '
                                      'capture is written; choose a --out outside it (to make a capture again from '
                                      'its own images/, copy them elsewhere first)\n')
  assert _snapshot(folder) == before


def test_out_as_the_photo_folder_is_refused_and_the_tools_own_files_there_are_never_photos(made, tmp_path,
                                                                                       monkeypatch, capsys):
  photos = tmp_path / 'photos'
  shutil.copytree(made[0], photos)
  before = _snapshot(photos)
  status, errout, _ = _cli(monkeypatch, capsys, photos, '--out', photos, '--overwrite')
  assert status == 2 and 'is inside --out' in errout and _snapshot(photos) == before
  # A capture an earlier version wrote beside the photos: its picture and report are not read as photos.
  for name in ('cameras.png', 'report.json', output.MANIFEST):
    shutil.copyfile(made[1] / name, photos / name)
  before = _snapshot(photos)
  with pytest.warns(UserWarning, match='written there by tools.capture: cameras.png, report.json'):
    assert capture.main([str(photos), '--out', str(tmp_path / 'capture'), '--max_size', MAX_SIZE]) == 0
  with open(tmp_path / 'capture' / 'report.json', encoding='utf-8') as f:
    report = json.load(f)
  assert sorted(os.listdir(tmp_path / 'capture' / 'images')) == sorted(PHOTOS)
  assert (report['photos'], report['skipped'], report['duplicates']) == (len(PHOTOS), [], {})
  assert _snapshot(photos) == before


def test_a_read_only_out_is_one_line_naming_it(made, tmp_path, monkeypatch, capsys):
  shared = tmp_path / 'shared'
  shutil.copytree(made[1], shared / 'capture')
  before = _snapshot(shared)
  with read_only(shared):
    status, errout, _ = _cli(monkeypatch, capsys, made[0], '--out', shared / 'new', '--max_size', MAX_SIZE)
    assert status == 2 and errout.startswith(f"error: --out {str(shared / 'new')!r} cannot be written: "), errout
    assert errout.endswith('choose a folder you can write to\n') and errout.count('\n') == 1, errout
    status, errout, _ = _cli(monkeypatch, capsys, made[0], '--out', shared / 'capture', '--overwrite')
    assert status == 2 and errout.startswith(f"error: --out {str(shared / 'capture')!r} cannot be written: "), errout
  assert _snapshot(shared) == before


def _fill(disk, leave: int) -> None:
  """Fills the disk but for `leave` bytes."""
  (disk / 'filler').write_bytes(b'\1' * (shutil.disk_usage(disk).free - leave))


def test_a_full_disk_is_one_line_naming_the_file_in_out_and_status_4(made, small_disk):
  before = _snapshot(made[0])
  photo_bytes = sum(os.path.getsize(made[0] / n) for n in PHOTOS)
  _fill(small_disk, photo_bytes // 2)  # Half the photos' copies in images/ fit.
  done = _subprocess(made[0], '--out', small_disk / 'full', '--max_size', MAX_SIZE)
  assert done.returncode == cli.DISK_FULL_STATUS and 'Traceback' not in done.stderr, done.stderr
  line = done.stderr.strip().splitlines()[-1]
  written = os.path.join(small_disk, 'full', 'images', '')
  assert line.startswith(f"error: no space left on the device writing '{written}"), done.stderr
  assert line.endswith("'; free disk space and run the same command again") and _snapshot(made[0]) == before


def test_a_disk_without_room_for_structure_from_motion_stops_before_it_in_one_line(made, small_disk):
  before = _snapshot(made[0])
  photo_bytes = sum(os.path.getsize(made[0] / n) for n in PHOTOS)
  _fill(small_disk, 2 * photo_bytes + (256 << 10))  # images/, the copies and 256 KiB: no room for the database.
  done = _subprocess(made[0], '--out', small_disk / 'full', '--max_size', MAX_SIZE)
  assert done.returncode == cli.DISK_FULL_STATUS and 'Traceback' not in done.stderr, done.stderr
  assert done.stderr.strip().splitlines()[-1].startswith(
      f"error: no space left on the device for structure-from-motion in '{small_disk / 'full' / 'sfm'}': its "
      f"database and models ('{small_disk / 'full' / 'sfm' / 'database.db'}', ...) may take "), done.stderr
  assert not os.path.exists(small_disk / 'full' / 'sfm' / 'database.db') and _snapshot(made[0]) == before


@pytest.mark.parametrize('module', ['tools.capture', 'tools.capture.bench', 'tools.capture.few_photos'])
def test_ctrl_c_while_it_imports_is_one_line(module, made, tmp_path):
  (tmp_path / 'sitecustomize.py').write_text(SIGINT_AT_JAX_IMPORT)
  done = subprocess.run([sys.executable, '-m', module, str(made[0]), '--out', str(tmp_path / 'capture')],
                        cwd=REPO, env=dict(os.environ, PYTHONPATH=str(tmp_path)), capture_output=True, text=True,
                        timeout=120, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), check=False)
  assert done.returncode == -signal.SIGINT, done.stderr  # Stopped by SIGINT: 130 in a shell.
  assert done.stderr == interrupt.MESSAGE + '\n' and not (tmp_path / 'capture').exists()


def test_ctrl_c_while_mapping_then_the_same_command_finishes_the_capture(made, tmp_path, monkeypatch, capsys):
  mapping = pycolmap.incremental_mapping

  def stopped(database, image_dir, folder, options):  # Writes a model's first file, as pycolmap does, then Ctrl-C.
    del database, image_dir, options
    os.makedirs(os.path.join(folder, '0'))
    open(os.path.join(folder, '0', 'cameras.bin'), 'wb').close()
    raise KeyboardInterrupt

  argv = (made[0], '--out', tmp_path / 'capture', '--max_size', MAX_SIZE)
  monkeypatch.setattr(pycolmap, 'incremental_mapping', stopped)
  status, errout, _ = _cli(monkeypatch, capsys, *argv)
  assert status == 130 and errout == interrupt.MESSAGE + '\n'
  assert os.listdir(tmp_path / 'capture' / 'sfm' / 'models' / 'attempt_0' / '0') == ['cameras.bin']
  monkeypatch.setattr(pycolmap, 'incremental_mapping', mapping)
  status, errout, out = _cli(monkeypatch, capsys, *argv)
  assert status == 0, errout
  assert out.startswith(f"{tmp_path / 'capture'}: replacing the unfinished capture there (its run stopped before "
                        'report.json)\n'), out
  assert not [n for n in os.listdir(tmp_path / 'capture' / 'sfm' / 'models') if n.startswith('attempt')]
  assert os.path.isfile(tmp_path / 'capture' / 'report.json')
