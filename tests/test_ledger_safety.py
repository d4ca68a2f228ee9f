"""What a GPU window of the ledger must not do, each checked in seconds on small stand-ins (an orbax checkpoint of a
few numbers, the tiny ledger of tests/test_ledger.py): lose steps it trained (a budget cut taken for a failure, a
retry over a trained run), train on the CPU, commit a damaged checkpoint, leave broken or half-made files behind, or
end a command in a traceback instead of one line."""

import io
import json
import os
import re
import subprocess
import sys
import tarfile

import numpy as np
import orbax.checkpoint as ocp
import pytest

from bench import ledger as ledger_lib
from bench import ledger_commit
from bench import prepare_lease
from internal import cli
from internal.run import checkpoints
from test_disk_full import small_disk  # pylint: disable=unused-import  (a fixture: a 32 MiB tmpfs)
from test_ledger import TINY_LEDGER
from test_read_only import read_only
from test_run_dir_errors import _one_error_line
from tools import pack_scene

ROOT = ledger_lib.ROOT
WINDOW = {'id': 'w1', 'date': '2026-01-01T00:00:00', 'device': 'cpu', 'platform': 'cpu', 'kind': 'cpu',
          'code': 'abc', 'key': 'cpu/abc', 'jax': '0', 'python': '3', 'budget_seconds': 530, 'time_variants': False}


@pytest.fixture(name='ledger')
def ledger_fixture(tmp_path):
  """The tiny ledger (its pack not made)."""
  (tmp_path / 'ledger.toml').write_text(TINY_LEDGER)
  return ledger_lib.load(str(tmp_path / 'ledger.toml'))


@pytest.fixture(name='tiny_pack', scope='module')
def tiny_pack_fixture(tmp_path_factory):
  """(ledger, data folder) of the tiny ledger with its pack, made once for the module."""
  folder = tmp_path_factory.mktemp('tiny_pack')
  (folder / 'ledger.toml').write_text(TINY_LEDGER)
  ledger = ledger_lib.load(str(folder / 'ledger.toml'))
  assert prepare_lease.make_packs(ledger, str(folder), str(folder / 'data')) == 0
  return ledger, str(folder / 'data')


def _command(capsys, *argv) -> tuple:
  """(exit status, stdout, stderr) of `python -m bench.ledger ARGV` run in this process."""
  status = cli.run(lambda: ledger_lib.main(list(argv)))
  printed = capsys.readouterr()
  return status, printed.out, printed.err


def _checkpoint(run_dir, step: int, value: float = 1.) -> None:
  """A checkpoint at step in run_dir as training saves one (orbax, checkpoints/STEP/default), of a few numbers."""
  mngr = checkpoints.manager(str(run_dir), 5)
  tree = {'params': {'mlp': {'kernel': np.full((4, 3), value, np.float32)}}, 'step': np.asarray(step, np.int32)}
  mngr.save(step, args=ocp.args.StandardSave(tree))
  mngr.wait_until_finished()
  mngr.close()


def _came_back(tmp_path, ledger, name: str, *steps, value: float = 1.):
  """What a window's $OUT holds after training the tiny run to its checkpoints at steps: pack and pack-window."""
  work, out = tmp_path / f'{name}_work', tmp_path / name
  run_dir = work / 'runs' / ledger.runs[0].name
  for step in steps:
    _checkpoint(run_dir, step, value)
  (run_dir / 'train.lock').write_text('')
  ledger_lib.write_json(str(work / 'window.json'), WINDOW)
  ledger_lib.write_json(str(work / 'outcomes.json'), {ledger.runs[0].name: {
      'from_step': 0, 'to_step': 0, 'steps': 30, 'variant': 'base', 'variant_bindings': [], 'evaluated': False,
      'packed': False}})
  out.mkdir()
  ledger_lib.pack(ledger, ledger.runs[0].name, str(work), str(out))
  ledger_lib.pack_window(str(work), str(out))
  return out


def _plain_tar(tmp_path, out, name: str) -> None:
  """The run's tar in out as bench/lease.sh writes it when `pack` failed: the run folder as it is, no sums."""
  subprocess.run(['tar', 'czf', str(out / 'run_tiny.tar.gz'), '-C', str(tmp_path / f'{name}_work' / 'runs' / 'tiny'),
                  '--exclude', './train.lock', '.'], check=True)


def _retar(tar_path, change) -> None:
  """Rewrites a run's tar after change(folder) altered its extracted files."""
  folder = str(tar_path) + '.d'
  ledger_lib.safe_extract(str(tar_path), folder)
  change(folder)
  with tarfile.open(tar_path, 'w:gz') as tar:
    tar.add(folder, '.')


def _committed(results) -> tuple:
  """(state.json, checkpoint.tar.gz's bytes) committed for the tiny run."""
  here = results / 'tiny'
  return json.loads((here / ledger_lib.STATE).read_text()), (here / ledger_lib.CHECKPOINT).read_bytes()


# A. A budget cut is never a failure; no retry drops steps a window trained.

def _stage(command: str, limit: int = 2) -> str:
  """What bench/stages.sh's stage prints for a command with a limit of `limit` s and 1 s of grace, then its status
  and stage_cut."""
  script = (f'budget=100 reserve=0 grace=1 stage_dir=$(mktemp -d); source bench/stages.sh; '
            f'stage s {limit} 1 bash -c {command!r}; echo "status=$? cut=$stage_cut"')
  return subprocess.run(['bash', '-c', script], cwd=ROOT, text=True, capture_output=True, timeout=60).stdout


def test_a_stage_the_budget_stops_is_a_cut_even_when_its_grace_runs_out():
  printed = _stage("trap '' TERM; sleep 30")  # Outlives its SIGTERM: SIGKILL the grace later.
  assert re.search(r'== s: status 137 after [34]s: cut by the budget\n', printed) and 'status=137 cut=1' in printed
  assert 'status=124 cut=1' in _stage('sleep 30')  # Stops on its SIGTERM.
  assert 'status=3 cut=0' in _stage('exit 3')  # A failure.
  assert 'status=124 cut=0' in _stage('exit 124')  # Its own status 124 before its limit: a failure too.


def test_a_skipped_stage_is_a_cut():
  script = ('budget=10 reserve=0 grace=1 stage_dir=$(mktemp -d); source bench/stages.sh; '
            'stage s 60 30 true; echo "status=$? cut=$stage_cut"')
  printed = subprocess.run(['bash', '-c', script], cwd=ROOT, text=True, capture_output=True, timeout=60).stdout
  assert '== s: skipped (9s of the budget left, it needs 30s)' in printed and 'status=1 cut=1' in printed


def test_the_lease_retries_only_a_failure_never_a_cut():
  with open(os.path.join(ROOT, 'bench', 'lease.sh')) as f:
    lease = f.read()
  assert re.search(r'if \(\(status != 0 && !stage_cut\)\) &&.*\n\s+stage "retry_\$RUN" \d+ \d+ "\$py" -m bench\.ledger '
                   r'retry-base', lease)


def test_a_new_run_that_trained_steps_is_not_retried_over_them(tiny_pack, tmp_path, capsys):
  (ledger, data), work = tiny_pack, tmp_path / 'work'
  run = ledger.runs[0]
  _checkpoint(work / 'runs' / run.name, 5)
  ledger_lib.write_json(str(work / 'outcomes.json'), {run.name: {'from_step': 0, 'packed': False, 'variant': 'pallas',
                                                                 'variant_bindings': ["MLP.dense_kernel = 'pallas'"]}})
  assert not ledger_lib.retry_base(ledger, str(work), data)
  assert 'failed after its checkpoint at step 5; no retry with base' in capsys.readouterr().out
  assert checkpoints.latest_step(str(work / 'runs' / run.name)) == 5
  assert ledger_lib.outcomes(str(work))[run.name]['variant'] == 'pallas'


def test_the_lease_ends_within_its_budget_with_a_minute_to_spare_in_the_device_call():
  with open(os.path.join(ROOT, 'bench', 'lease.sh')) as f:
    lease = f.read()
  budget = int(re.search(r'budget=\$\{BUDGET:-(\d+)\}', lease).group(1))
  grace = int(re.search(r'grace=\$\{GRACE:-(\d+)\}', lease).group(1))
  assert budget + 60 <= prepare_lease.TIMEOUT_S <= 600
  parts = dict(re.findall(r'(\w+_s)=(\d+)', re.search(r'\npack_s=.*', lease).group(0)))
  reserve = subprocess.run(['bash', '-c', ' '.join(f'{k}={v}' for k, v in parts.items()) + '; ' + re.search(
      r'\n(reserve=\$\(\(.*\)\))', lease).group(1) + '; echo $reserve'], text=True, capture_output=True).stdout
  # What follows the last stage, each command with its limit: a run's pack and its SIGKILL, its plain tar, the
  # window's pack and its SIGKILL, its plain tar, 5 s for the script's lines.
  assert int(reserve) == sum(int(parts[k]) for k in ('pack_s', 'kill_s', 'tar_s', 'window_s', 'kill_s', 'tar_s')) + 5
  assert f'timeout -k "$kill_s" "$pack_s" "$py" -m bench.ledger pack "$RUN"' in lease
  assert f'timeout -k "$kill_s" "$window_s" "$py" -m bench.ledger pack-window' in lease
  assert lease.count('timeout -s KILL "$tar_s" tar czf') == 2 and lease.count('timeout ') == 4
  assert budget - int(reserve) - grace > 300  # Training's SIGTERM by then: most of the window.


# B. A window trains on a GPU.

def test_the_lease_where_jax_sees_no_gpu_says_so_in_one_line_and_packs_nothing(tiny_pack, tmp_path):
  (ledger, data), out = tiny_pack, tmp_path / 'out'
  env = {**os.environ, 'OUT': str(out), 'PYTHON': sys.executable, 'LEASE_WORK': str(tmp_path / 'work'),
         'LEDGER': ledger.path, 'RESULTS': str(tmp_path / 'results'), 'DATA': data, 'STOP_AT_STEP': '1'}
  env.pop('LEASE_ON_CPU', None)
  result = subprocess.run(['bash', 'bench/lease.sh'], cwd=ROOT, env=env, text=True, capture_output=True, timeout=300)
  assert result.returncode == cli.USAGE_ERROR_STATUS, result.stdout
  errors = [line for line in result.stdout.splitlines() if line.startswith('error: ')]
  assert len(errors) == 1 and errors[0].startswith('error: jax sees no GPU (its device: cpu'), result.stdout
  assert 'Traceback' not in result.stdout and '== next' not in result.stdout and '== train' not in result.stdout
  assert os.listdir(out) == ['lease.log'] and not (tmp_path / 'work' / 'window.json').exists()


# C. A checkpoint is verified before it replaces the committed one; a bad tar is one line.

def _flip_a_byte(folder) -> None:
  data = max((os.path.join(d, f) for d, _, files in os.walk(os.path.join(folder, 'checkpoints')) for f in files
              if os.path.basename(d) == 'd'), key=os.path.getsize)  # A file of the values.
  with open(data, 'r+b') as f:
    f.seek(os.path.getsize(data) // 2)
    byte = f.read(1)
    f.seek(-1, 1)
    f.write(bytes([byte[0] ^ 0xff]))


@pytest.mark.parametrize('damage, message', [
    ('flipped', "checkpoint step 10 differs from the SHA-256 sums `pack` wrote in checkpoints/10/default/"),
    ('nan', "checkpoint step 10 holds non-finite values in ['params']['mlp']['kernel']"),
    ('nan_plain_tar', "checkpoint step 10 holds non-finite values in ['params']['mlp']['kernel']"),
    ('outside', "(OutsideDestinationError: '../../X' would be extracted to"),
    ('cut_short', '(EOFError: Compressed file ended before the end-of-stream marker was reached)')])
def test_unpack_refuses_a_damaged_checkpoint_or_tar_in_one_line_and_keeps_the_committed_one(
    ledger, tmp_path, capsys, damage, message):
  results = tmp_path / 'results'
  flags = ('--ledger', ledger.path, '--results', str(results))
  assert _command(capsys, 'unpack', str(_came_back(tmp_path, ledger, 'first', 5)), *flags)[0] == 0
  before = _committed(results)
  out = _came_back(tmp_path, ledger, 'second', 10, value=np.nan if damage.startswith('nan') else 1.)
  tar = out / 'run_tiny.tar.gz'
  if damage == 'flipped':
    _retar(tar, _flip_a_byte)
  elif damage == 'nan_plain_tar':
    _plain_tar(tmp_path, out, 'second')
  elif damage == 'outside':
    with tarfile.open(tar, 'w:gz') as bad:
      bad.addfile(tarfile.TarInfo('../../X'), io.BytesIO(b''))
  elif damage == 'cut_short':
    tar.write_bytes(tar.read_bytes()[:tar.stat().st_size // 2])
  status, _, errout = _command(capsys, 'unpack', str(out), *flags)
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, repr(str(tar)), message)
  assert 'Traceback' not in errout and _committed(results) == before
  assert not (tmp_path / 'X').exists()


def test_a_plain_tar_without_sums_is_committed_when_its_checkpoint_restores_finite(ledger, tmp_path, capsys):
  out = _came_back(tmp_path, ledger, 'plain', 5)
  _plain_tar(tmp_path, out, 'plain')
  status, printed, _ = _command(capsys, 'unpack', str(out), '--ledger', ledger.path, '--results',
                                str(tmp_path / 'results'))
  assert status == 0 and 'no SHA-256 sums' in printed and _committed(tmp_path / 'results')[0]['step'] == 5


# D. A missing checkpoint or run folder, a pack table without bindings: one line each.

def test_next_names_a_committed_step_whose_checkpoint_is_missing(tiny_pack, tmp_path, capsys):
  ledger, data = tiny_pack
  results = tmp_path / 'results'
  ledger_lib.write_json(str(results / 'tiny' / ledger_lib.STATE), {'step': 5, 'evaluated': False, 'variant': 'base',
                                                                   'variant_bindings': [], 'windows': []})
  status, _, errout = _command(capsys, 'next', '--work', str(tmp_path / 'work'), '--ledger', ledger.path,
                               '--results', str(results), '--data', data)
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, repr(str(results / 'tiny' / ledger_lib.CHECKPOINT)), 'is missing', 'at step 5')
  assert not (tmp_path / 'work' / 'runs' / 'tiny').exists()


def test_pack_without_the_run_folder_writes_nothing(ledger, tmp_path, capsys):
  (tmp_path / 'out').mkdir()
  status, _, errout = _command(capsys, 'pack', 'tiny', '--work', str(tmp_path / 'work'), '--out',
                               str(tmp_path / 'out'), '--ledger', ledger.path)
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, repr(str(tmp_path / 'work' / 'runs' / 'tiny')), 'does not exist')
  assert not os.listdir(tmp_path / 'out')


@pytest.mark.parametrize('field', ['gin', 'data', 'bindings'])
def test_a_pack_table_without_a_field_is_named_when_the_ledger_loads(tmp_path, field):
  text = re.sub(rf'(\[pack\.tiny\][^\[]*?)\n{field} = [^\n]*', r'\1', TINY_LEDGER)
  assert text != TINY_LEDGER
  (tmp_path / 'l.toml').write_text(text)
  with pytest.raises(ValueError, match=rf"\[pack.tiny\]: {field} = None; expected a"):
    ledger_lib.load(str(tmp_path / 'l.toml'))


# E. A refused `next` leaves nothing behind.

def test_next_without_the_pack_says_the_same_line_twice_and_leaves_nothing(ledger, tmp_path, capsys):
  (tmp_path / 'empty').mkdir()
  argv = ('next', '--work', str(tmp_path / 'work'), '--data', str(tmp_path / 'empty'), '--ledger', ledger.path,
          '--results', str(tmp_path / 'results'))
  first, second = _command(capsys, *argv), _command(capsys, *argv)
  assert first == second and first[0] == cli.USAGE_ERROR_STATUS
  _one_error_line(first[2], repr(str(tmp_path / 'empty' / 'tiny.npz')), 'is missing', 'bench.prepare_lease')
  assert not (tmp_path / 'work' / 'runs').exists()


# F, G. tools.pack_scene's one line, passed on by bench.prepare_lease.

@pytest.mark.parametrize('disk', ['read_only', 'full'])
def test_prepare_lease_passes_on_the_packs_one_line_and_status(ledger, tmp_path, request, monkeypatch, capfd, disk):
  data = (request.getfixturevalue('small_disk') if disk == 'full' else tmp_path) / 'devdata'
  data.mkdir()
  monkeypatch.setattr(ledger_lib, 'DATA', str(data))  # Absolute: in place of the repository's .devdata.
  pack = str(data / 'tiny.npz')
  argv = ['--offline', '--data_root', str(tmp_path), '--ledger', ledger.path]
  if disk == 'full':
    filler = data.parent / 'filler'
    with open(filler, 'wb') as f:  # All but 16 KiB: the pack is larger.
      f.write(b'\1' * (os.statvfs(data).f_bavail * os.statvfs(data).f_frsize - 16 * 2**10))
    status = cli.run(lambda: prepare_lease.main(argv))
    _one_error_line(capfd.readouterr().err, f'no space left on the device writing {pack!r}')
    assert status == cli.DISK_FULL_STATUS
  else:
    with read_only(data):
      status = cli.run(lambda: prepare_lease.main(argv))
    _one_error_line(capfd.readouterr().err, f'--out {pack!r} cannot be written', 'expected a writable folder')
    assert status == cli.USAGE_ERROR_STATUS
  assert not os.listdir(data)  # No pack, no partial file.


def test_pack_scene_names_an_out_folder_that_does_not_exist(tmp_path, capsys):
  out = str(tmp_path / 'no_such' / 'scene.npz')
  status = cli.run(lambda: pack_scene.main(['--gin_configs', 'configs/demo.gin', '--out', out]))
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(capsys.readouterr().err, f'--out {out!r}', 'does not exist')


# H. What the ledger packs, and the older-than-committed check, in seconds.

def test_pack_keeps_the_newest_checkpoint_alone_with_its_sums(ledger, tmp_path):
  out = _came_back(tmp_path, ledger, 'two', 5, 10)
  with tarfile.open(out / 'run_tiny.tar.gz') as tar:
    names, files = tar.getnames(), [m.name for m in tar.getmembers() if m.isfile()]
    sums = json.load(tar.extractfile(f'./{ledger_lib.SUMS}'))
  assert sorted(n for n in names if n.count('/') == 2 and n.startswith('./checkpoints/')) == ['./checkpoints/10']
  assert './train.lock' not in names and sums['step'] == 10
  assert sorted(sums['sha256']) == sorted(n[2:] for n in files if n.startswith('./checkpoints/10/'))


def test_unpack_refuses_a_checkpoint_older_than_the_committed_one(ledger, tmp_path, capsys):
  results = tmp_path / 'results'
  flags = ('--ledger', ledger.path, '--results', str(results))
  assert _command(capsys, 'unpack', str(_came_back(tmp_path, ledger, 'newer', 10)), *flags)[0] == 0
  before = _committed(results)
  out = _came_back(tmp_path, ledger, 'older', 5)
  status, _, errout = _command(capsys, 'unpack', str(out), *flags)
  assert status == cli.USAGE_ERROR_STATUS
  _one_error_line(errout, 'holds tiny at step 5, older than the committed step 10', 'nothing of it is committed')
  assert _committed(results) == before
