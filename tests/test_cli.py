"""The scripts' command line: every form of the multi-value flags, user errors as one line with status 2."""

import io
import signal
import subprocess
import sys

import pytest
import tqdm

from internal.run import checkpoints
from internal import cli
from internal.run import run_dir
from internal.training import train_step
from internal import progress
from test_checkpoints import DEMO, ROOT


@pytest.mark.parametrize('argv', [
    ['--gin_bindings', 'A = 1', 'B = 2', '--gin_configs', 'x.gin', 'y.gin'],          # Space-separated.
    ['--gin_bindings=A = 1', '--gin_bindings=B = 2', '--gin_configs=x.gin', '--gin_configs=y.gin'],  # Repeated.
    ['--gin_bindings=A = 1', 'B = 2', '--gin_configs=x.gin', 'y.gin'],                # `--flag="A" "B"`.
    ['--gin_configs', 'x.gin', '--gin_bindings=A = 1', '--gin_configs=y.gin', '--gin_bindings', 'B = 2'],
])
def test_every_form_of_the_multi_value_flags(argv):
  args = cli.flag_parser('test').parse_args(argv)
  assert args.gin_configs == ['x.gin', 'y.gin'] and args.gin_bindings == ['A = 1', 'B = 2']


def test_a_tools_own_multi_value_flags_take_every_form_too():
  parser = cli.flag_parser('test', ['--compare_bindings'])
  parser.add_argument('--compare_bindings', action='extend', nargs='+', default=[])
  parser.add_argument('--other', action='extend', nargs='+', default=[])  # Not named: '=' keeps one value.
  args = parser.parse_args(['--compare_bindings=A = 1', 'B = 2', '--gin_bindings=C = 3', 'D = 4', '--other=x=1'])
  assert args.compare_bindings == ['A = 1', 'B = 2'] and args.gin_bindings == ['C = 3', 'D = 4']
  assert args.other == ['x=1']
  own = cli.FlagParser(multi_value_flags=['--seeds'])  # Only the flags it is given.
  own.add_argument('--seeds', action='extend', nargs='+', default=[])
  own.add_argument('--gin_bindings', action='extend', nargs='+', default=[])
  assert own.parse_args(['--seeds=1', '2']).seeds == ['1', '2']
  args, rest = own.parse_known_args(['--gin_bindings=a=1', 'b=2'])
  assert args.gin_bindings == ['a=1'] and rest == ['b=2']


def test_recorded_command_lines_give_the_shell_back_the_same_words():
  words = ['--gin_bindings', "Config.data_dir = 'my scans'", "--gin_bindings=Config.near='a'", 'a$HOME', 'say "hi"',
           '', 'plain/path-1.gin', "it's"]
  line = cli.command_line('tools.study', words)
  assert line.startswith('python -m tools.study --gin_bindings "Config.data_dir = \'my scans\'" ')
  echoed = subprocess.run(['bash', '-c', f'printf "%s\\n" {line}'], capture_output=True, text=True, check=True)
  assert echoed.stdout.split('\n')[:-1] == ['python', '-m', 'tools.study'] + words


def test_other_flags_keep_their_equals_form():
  parser = cli.flag_parser('test')
  parser.add_argument('--stop_at_step', type=int, default=0)
  args = parser.parse_args(['--stop_at_step=5', '--gin_bindings=Config.near = 1.'])
  assert args.stop_at_step == 5 and args.gin_bindings == ['Config.near = 1.']


def _raising(err):
  def main():
    raise err
  return main


@pytest.mark.parametrize('err', [
    ValueError('Config.near = 0.0; expected > 0\n  In bindings string line 1'),
    FileNotFoundError('no data'), FileExistsError('done already'), run_dir.RunDirError('other settings'),
    checkpoints.NoCheckpointError('no checkpoint')])
def test_user_errors_print_one_line_and_exit_2(err, capsys, monkeypatch):
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  assert cli.run(_raising(err)) == cli.USAGE_ERROR_STATUS == 2
  out, errout = capsys.readouterr()
  assert out == '' and errout.count('\n') == 1 and errout.startswith(f'error: {str(err).splitlines()[0]}')
  monkeypatch.setenv(cli.DEBUG_ENV, '1')
  with pytest.raises(type(err)):
    cli.run(_raising(err))


def test_a_run_stopped_for_non_finite_values_prints_one_line_and_exits_3(capsys, monkeypatch):
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  err = train_step.NonFiniteError('steps 3-6: 4 consecutive updates skipped')
  assert cli.run(_raising(err)) == cli.NONFINITE_STATUS == 3
  assert capsys.readouterr().err == f'error: {err}\n'


def test_bugs_keep_their_traceback(monkeypatch):
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  with pytest.raises(KeyError):
    cli.run(_raising(KeyError('a bug')))
  assert cli.run(lambda: 0) == 0


def test_one_line_joins_multi_line_messages():
  assert cli.one_line(ValueError("No configurable 'Foo'.\n  In bindings string line 1\n    Foo.x = 1")) == (
      "No configurable 'Foo'. In bindings string line 1 Foo.x = 1")


def test_progress_off_a_terminal_writes_whole_lines():
  stream = io.StringIO()
  bar = tqdm.tqdm(total=3, unit='step', **progress.progress_kwargs(stream))
  for _ in range(3):
    bar.update(1)
  bar.close()
  text = stream.getvalue()
  assert '\r' not in text and text.endswith('\n') and '3/3' in text.splitlines()[-1]


def test_a_non_utf8_path_is_a_one_line_error_not_a_crash(tmp_path):
  binding = b"Config.checkpoint_dir = '" + bytes(tmp_path) + b"/run\xff'"
  proc = subprocess.run([sys.executable.encode(), b'train.py', b'--gin_configs', DEMO.encode(),
                         b'--gin_bindings', binding, b'Config.max_steps = 1'], cwd=ROOT, capture_output=True,
                        timeout=120, check=False)
  err = proc.stderr.decode('utf-8')
  assert proc.returncode == 2 and err.count('\n') == 1 and err.startswith('error: cannot parse the gin'), err
  assert '\\udcff' in err and 'lost sys.stderr' not in err


def test_after_ctrl_c_further_ctrl_c_is_ignored_to_the_exit(capsys):
  def interrupted():
    raise KeyboardInterrupt
  previous = signal.getsignal(signal.SIGINT)
  try:
    assert cli.run(interrupted) == 128 + signal.SIGINT
    assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN  # A second Ctrl-C cannot kill the exit's cleanup.
  finally:
    signal.signal(signal.SIGINT, previous)
  assert capsys.readouterr().err.startswith('interrupted:')
