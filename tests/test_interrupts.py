"""Ctrl-C during eval.py and render.py: one line and exit status 130, as training stopped by SIGINT; the rerun
finishes the work. Ctrl-C while a script or a tool imports: the same line."""

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from conftest import JAX_CACHE
from internal import cli
from internal import interrupt
from internal.evaluation import render_path
from internal.pipeline import loop
from test_checkpoints import DEMO, ROOT, TINY, _read_stderr, tiny_config

FRAMES = 40
# Small render chunks make every view and frame slow enough to be interrupted halfway.
BINDINGS = ('Config.max_steps = 2', f'Config.render_path_frames = {FRAMES}', 'Config.compute_lpips = False',
            'Config.render_chunk_size = 8')


@pytest.fixture(scope='module')
def finished_run(tmp_path_factory, scene_dir):
  run = tmp_path_factory.mktemp('interrupted') / 'run'
  loop.train(tiny_config(scene_dir, run, *BINDINGS))
  return run


def _interrupt(script: str, run, scene_dir, started) -> tuple:
  """(exit status, stderr) of script on run sent SIGINT once started(stdout + stderr so far) is true."""
  flags = [*TINY, *BINDINGS, f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{run}'"]
  env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=JAX_CACHE, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0',
             PYTHONUNBUFFERED='1')
  env.pop(cli.DEBUG_ENV, None)
  # SIGINT back to its default in the child: a shell running the suite in the background (nohup ... &) ignores it,
  # and Python started with SIGINT ignored never raises KeyboardInterrupt.
  proc = subprocess.Popen([sys.executable, script, '--gin_configs', DEMO, '--gin_bindings', *flags], cwd=ROOT,
                          env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
  chunks, out = [], []
  threading.Thread(target=_read_stderr, args=(proc, chunks), daemon=True).start()
  threading.Thread(target=lambda: out.extend(line.decode() for line in proc.stdout), daemon=True).start()
  deadline = time.time() + 120
  while not started(''.join(out) + ''.join(chunks)) and proc.poll() is None and time.time() < deadline:
    time.sleep(0.05)
  assert proc.poll() is None, 'finished before it could be interrupted: ' + ''.join(chunks)[-2000:]
  proc.send_signal(signal.SIGINT)
  status = proc.wait(timeout=60)
  time.sleep(0.2)
  return status, ''.join(chunks)


def _assert_one_interrupted_line(status: int, errout: str) -> None:
  assert status == cli.signal_status(signal.SIGINT) == 130, errout[-3000:]
  assert 'Traceback' not in errout and 'KeyboardInterrupt' not in errout, errout[-3000:]
  assert errout.strip().splitlines()[-1].startswith('interrupted: stopped by Ctrl-C (SIGINT)'), errout[-3000:]


def test_ctrl_c_during_eval_stops_in_one_line_and_the_rerun_evaluates(finished_run, scene_dir):
  status, errout = _interrupt('eval.py', finished_run, scene_dir, lambda text: 'view ' in text)
  _assert_one_interrupted_line(status, errout)
  preds = finished_run / 'test_preds_step_2'
  assert not (preds / 'metrics.json').exists()  # Written last: an interrupted evaluation is not one.
  done = subprocess.run([sys.executable, 'eval.py', '--gin_configs', DEMO, '--gin_bindings', *TINY, *BINDINGS,
                         f"Config.data_dir = '{scene_dir}'", f"Config.checkpoint_dir = '{finished_run}'",
                         'Config.render_chunk_size = 1280'], cwd=ROOT, capture_output=True, text=True, check=False)
  assert done.returncode == 0 and (preds / 'metrics.json').exists(), done.stderr[-2000:]


def test_ctrl_c_during_render_stops_in_one_line_and_is_not_taken_for_a_render(finished_run, scene_dir):
  renders = finished_run / 'path_renders_step_2'
  # Started once a frame is on disk (in a pipe the progress line comes every 5 s: a fast machine may be done by then).
  status, errout = _interrupt('render.py', finished_run, scene_dir,
                              lambda _: (renders / 'color_000.png').exists())
  _assert_one_interrupted_line(status, errout)
  config = tiny_config(scene_dir, finished_run, *BINDINGS)
  assert os.listdir(renders) and not render_path.existing_renders(config)
  render_path.render(config)  # Renders again what was interrupted, without Config.overwrite.
  assert render_path.existing_renders(config)


def test_a_render_stopped_while_writing_its_videos_is_not_complete(finished_run, scene_dir, tmp_path, monkeypatch):
  config = tiny_config(scene_dir, finished_run, *BINDINGS, 'Config.render_path_frames = 2',
                       f"Config.output_dir = '{tmp_path}'")

  def stopped(frames, path):
    raise KeyboardInterrupt

  monkeypatch.setattr(render_path, 'can_write_video', lambda: True)
  monkeypatch.setattr(render_path, 'write_video', stopped)
  with pytest.raises(KeyboardInterrupt):
    render_path.render(config)
  assert (tmp_path / 'path_renders_step_2' / 'color_001.png').exists()  # Every frame, yet no complete render.
  assert not render_path.existing_renders(config)
  monkeypatch.setattr(render_path, 'write_video', lambda frames, path: open(path, 'wb').close())
  render_path.render(config)
  assert render_path.existing_renders(config)


# Put on PYTHONPATH as sitecustomize.py: the process sends itself SIGINT when it starts importing jax, as Ctrl-C
# in the first seconds of a script does (its imports take seconds on a loaded machine).
SIGINT_AT_JAX_IMPORT = '''
import os, signal, sys

class SigintAtJax:
  def find_spec(self, name, path=None, target=None):
    if name == 'jax':
      os.kill(os.getpid(), signal.SIGINT)
    return None

sys.meta_path.insert(0, SigintAtJax())
'''


@pytest.mark.parametrize('script', ['eval.py', 'train.py', 'render.py', 'tools.study', 'tools.mesh',
                                    'tools.demo_seeds', 'tools.tables', 'tools.pack_scene'])
def test_ctrl_c_while_a_script_or_tool_imports_is_one_line(script, tmp_path):
  (tmp_path / 'sitecustomize.py').write_text(SIGINT_AT_JAX_IMPORT)
  env = dict(os.environ, PYTHONPATH=str(tmp_path))
  env.pop(cli.DEBUG_ENV, None)
  command = [script] if script.endswith('.py') else ['-m', script]  # A tool runs as `python -m tools.<name>`.
  result = subprocess.run([sys.executable, *command], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), check=False)
  assert result.returncode == -signal.SIGINT, result.stderr  # Stopped by SIGINT: 130 in a shell.
  assert result.stderr == interrupt.MESSAGE + '\n'


def _command(module: str, tmp_path) -> list:
  """A command line of module (a script or tool) that reads a run which does not exist (it ends at once after its
  imports: a Ctrl-C it missed shows)."""
  command = [module] if module.endswith('.py') else ['-m', module]
  return [sys.executable, *command, '--gin_configs', DEMO, '--gin_bindings',
          f"Config.checkpoint_dir = '{tmp_path / 'no_run'}'"]


def _run_with_sitecustomize(command, site: str, tmp_path, **kwargs) -> subprocess.Popen:
  """command started with site as its sitecustomize.py and SIGINT at its default (see _interrupt)."""
  (tmp_path / 'sitecustomize.py').write_text(site)
  env = dict(os.environ, PYTHONPATH=str(tmp_path))
  env.pop(cli.DEBUG_ENV, None)
  return subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), **kwargs)


def _assert_stopped_in_one_line(proc: subprocess.Popen) -> None:
  """proc ends with the one interrupted line: by SIGINT (Python's exit after a KeyboardInterrupt) or with status 130
  (cli.run's), both 130 in a shell."""
  _, errout = proc.communicate(timeout=120)
  assert proc.returncode in (-signal.SIGINT, cli.signal_status(signal.SIGINT)), errout
  assert errout == interrupt.MESSAGE + '\n'


# As sitecustomize.py: Ctrl-C while jax is imported, its KeyboardInterrupt then turned into another exception (as a
# compiled module's initialization does), swallowed (a library's `except ImportError:` fallback) or dropped by a
# callback that Python reports as unraisable (a garbage collection callback's).
INTERRUPTED_IMPORT = '''
import os, signal, sys, time

HOW = {how!r}

class Unraisable:
  def __del__(self):
    os.kill(os.getpid(), signal.SIGINT)

class InterruptedImport:
  def find_spec(self, name, path=None, target=None):
    if name != 'jax':
      return None
    sys.meta_path.remove(self)
    if HOW == 'dropped':
      Unraisable()
      return None
    try:
      os.kill(os.getpid(), signal.SIGINT)
      time.sleep(10)
    except KeyboardInterrupt:
      if HOW == 'turned':
        raise ImportError('Encountered an error while initializing the extension.') from None
    return None

sys.meta_path.insert(0, InterruptedImport())
'''


@pytest.mark.parametrize('how', ['turned', 'swallowed', 'dropped'])
@pytest.mark.parametrize('module', ['tools.mesh', 'eval.py'])
def test_ctrl_c_during_an_import_is_one_line_whatever_the_import_makes_of_it(module, how, tmp_path):
  _assert_stopped_in_one_line(_run_with_sitecustomize(_command(module, tmp_path),
                                                      INTERRUPTED_IMPORT.format(how=how), tmp_path))


# As sitecustomize.py: creates the file READY at the first import once the script set up its Ctrl-C handling.
SAYS_READY = '''
import signal, sys

class SaysReady:
  def find_spec(self, name, path=None, target=None):
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler or sys.excepthook is not sys.__excepthook__:
      sys.meta_path.remove(self)
      open({ready!r}, 'w').close()
    return None

sys.meta_path.insert(0, SaysReady())
'''


@pytest.mark.parametrize('delay', [0., 0.05, 0.1, 0.2, 0.35, 0.5])
def test_ctrl_c_at_any_moment_of_a_tools_imports_is_one_line(delay, tmp_path):
  ready = tmp_path / 'ready'
  proc = _run_with_sitecustomize(_command('tools.mesh', tmp_path), SAYS_READY.format(ready=str(ready)), tmp_path)
  deadline = time.time() + 60
  while not ready.exists() and proc.poll() is None and time.time() < deadline:
    time.sleep(0.005)
  time.sleep(delay)
  assert proc.poll() is None, proc.communicate()
  proc.send_signal(signal.SIGINT)
  _assert_stopped_in_one_line(proc)


@pytest.fixture
def python_sigint(monkeypatch):
  """SIGINT handled by Python's default handler for the test (as in a script), not ignored."""
  monkeypatch.setattr(sys, 'unraisablehook', sys.unraisablehook)
  previous = signal.signal(signal.SIGINT, signal.default_int_handler)
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  yield
  signal.signal(signal.SIGINT, previous)


def _ctrl_c() -> None:
  """Sends this process SIGINT and waits for its KeyboardInterrupt."""
  os.kill(os.getpid(), signal.SIGINT)
  time.sleep(10)
  raise AssertionError('no KeyboardInterrupt')


def test_any_exception_after_ctrl_c_is_the_interruption(python_sigint, capsys):
  def main():
    try:
      _ctrl_c()
    except KeyboardInterrupt:
      raise ImportError("Failed to import 'zlib.decompress' - cannot initialise module strings") from None
  assert cli.run(main) == 130
  assert capsys.readouterr().err == interrupt.MESSAGE + '\n'
  assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN  # As after a KeyboardInterrupt: ignored to the exit.


def test_without_ctrl_c_exceptions_keep_their_meaning(python_sigint, capsys):
  with pytest.raises(ImportError):
    cli.run(lambda: exec('raise ImportError("a bug")'))
  assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Put back as it was.


def test_a_ctrl_c_that_the_imports_swallowed_stops_the_script_before_main(python_sigint, capsys):
  recorder = interrupt.Recorder()
  assert recorder.install()  # As a script's first statement does.
  try:
    try:
      _ctrl_c()
    except KeyboardInterrupt:
      pass  # A library's fallback.
    assert cli.run(lambda: pytest.fail('main ran')) == 130
  finally:
    recorder.uninstall()
  assert capsys.readouterr().err == interrupt.MESSAGE + '\n'


class _SigintWhenCollected:
  def __del__(self):
    os.kill(os.getpid(), signal.SIGINT)


def test_a_ctrl_c_that_a_callback_dropped_still_stops_the_command(python_sigint, capsys):
  def main():
    _SigintWhenCollected()  # Its KeyboardInterrupt is raised in __del__, which Python only reports.
    time.sleep(10)
    return 0
  assert cli.run(main) == 130
  assert capsys.readouterr().err == interrupt.MESSAGE + '\n'  # Without Python's 'Exception ignored in ...'.
