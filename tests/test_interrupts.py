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
