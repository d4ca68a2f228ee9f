"""Every ```bash block of README.md and docs/*.md runs as written (with tiny settings), so that they cannot drift.

Each block runs in bash in a copy of the repository, with one scene per loop (the README's scene-list variables)
and a `python` on PATH that appends tiny model and data bindings to train.py / eval.py / render.py and to the
tools that take them (tools.study, tools.pack_scene, tools.mesh, tools.points, tools.synthetic_depth, tools.view):
the shared scenes instead of data/, 2 steps, a small model, low resolution (tools.mesh: a 16^3 grid at a level a
2-step field crosses; tools.points: every pixel's point; a paper table's study: its first cell; tools.capture: 18 of
the shared cup's photos as the `photos` folder, at half size; tools.view, a server: a free port, and Ctrl-C once it
serves, its way out). It turns `python -m pytest` into a collection run (the suite is not run inside itself).
`python3 -m venv`, `. .venv/bin/activate` and `pip install` steps are dropped: the test runs in the installed
environment (the GPU install, `pip install -r requirements-gpu.txt`, cannot run on a CPU machine;
tests/test_gpu_install.py checks that it resolves).
"""

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from conftest import SHARED_DATA
from conftest import JAX_CACHE
from test_checkpoints import ROOT

README = ROOT / 'README.md'
DOCUMENTS = [README] + sorted((ROOT / 'docs').glob('*.md'))


def bash_blocks(path) -> list:
  """The ```bash blocks of a Markdown file, in order."""
  return re.findall(r'^```bash\n(.*?)^```', path.read_text(), re.S | re.M)


BLOCKS = [(f'{path.relative_to(ROOT)}:{i}', block) for path in DOCUMENTS for i, block in enumerate(bash_blocks(path))]
INSTALL_STEP = re.compile(r'^(python3 -m venv .*|\. \.venv/bin/activate|pip install .*)$')
LOOP_VARIABLES = {'DATA_ROOT': str(SHARED_DATA), 'DTU_SCANS': 'scan8', 'LLFF_SCENES': 'fern', 'BLENDER_SCENES': 'lego', 'VIEWS': '3',
                  'METHODS': 'mipnerf', 'T_VALUES': '4395'}
TINY = ['MLP.net_depth = 2', 'MLP.net_width = 16', 'MLP.net_width_viewdirs = 16', 'MipNerfModel.num_samples = 8',
        'NerfMLP.net_depth = 2', 'NerfMLP.net_width = 16', 'NerfMLP.net_width_viewdirs = 8', 'NerfMLP.skip_layer = 0',
        'NerfModel.num_coarse_samples = 8', 'NerfModel.num_fine_samples = 8',
        'Config.max_steps = 2', 'Config.batch_size = 64', 'Config.print_every = 1', 'Config.train_render_every = 0',
        'Config.render_path_frames = 2', 'Config.eval_test_ids = [0]', 'Config.compute_lpips = False',
        'Config.allow_missing_test_views = True', 'Config.generated_size = (16, 20)']
# Per dataset (recognised in the gin config's name): the shared scene and a low resolution.
DATA = {
    'dtu': [f"Config.data_dir = '{SHARED_DATA / 'dtu'}'", "Config.dtu_scan = 'dtu_scan24'",
            f"Config.dtu_mask_path = '{SHARED_DATA / 'dtu'}'", 'Config.factor = 16', 'Config.render_factor = 16'],
    'llff': [f"Config.data_dir = '{SHARED_DATA / 'llff'}'", "Config.llff_scan = 'fern'", 'Config.factor = 32',
             'Config.render_factor = 32'],
    'blender': [f"Config.data_dir = '{SHARED_DATA / 'blender'}'", "Config.blender_scene = 'lego'",
                'Config.factor = 16', 'Config.render_factor = 16'],
    'capture': ['Config.factor = 8', 'Config.render_factor = 8', 'Config.curve_factor = 1'],  # The block's capture.
}
# The README's `photos` folder: 18 of the cup's photos (17 registered give the 3 test views that the capture config's
# learning curve needs; 16.jpg, which registers at full size only, is left out).
CAPTURE_PHOTOS = [f'{i}.jpg' for i in list(range(1, 16)) + [18, 19, 20]]
SHARED_SCENES = {'dtu': SHARED_DATA / 'dtu' / 'dtu_scan24', 'llff': SHARED_DATA / 'llff' / 'fern',
                 'blender': SHARED_DATA / 'blender' / 'lego', 'capture': SHARED_DATA / 'colmap' / 'cup'}
SHIM = '''#!{python}
"""README test shim: runs the real interpreter with tiny bindings appended; logs each call and its status."""
import json, subprocess, sys
args = sys.argv[1:]
TAKES_BINDINGS = (['-m', 'tools.study'], ['-m', 'tools.pack_scene'], ['-m', 'tools.mesh'],
                  ['-m', 'tools.points'], ['-m', 'tools.synthetic_depth'], ['-m', 'tools.view'])
if args[:1] in (['train.py'], ['eval.py'], ['render.py']) or args[:2] in (TAKES_BINDINGS):
  configs = ' '.join(a for a in args if 'configs/' in a or 'studies/' in a)
  args += ['--gin_bindings'] + {tiny!r} + [x for name, extra in {data!r}.items() if name in configs for x in extra]
if args[:2] == ['-m', 'tools.study'] and any('studies/table_' in a for a in args):  # A table: its first cell.
  args += ['--shard', '0/1000']
if args[:2] == ['-m', 'tools.mesh']:  # A 2-step field crosses softplus(-1), the density of a zero pre-activation.
  args += ['--resolution', '16', '--level', '0.3133']
elif args[:2] == ['-m', 'tools.points']:  # A 2-step field is nowhere near opaque: keep every pixel's point.
  args += ['--min_opacity', '0.001', '--min_views', '1']
elif args[:2] == ['-m', 'tools.capture']:  # Structure-from-motion at half size.
  args += ['--max_size', '400']
elif args[:2] == ['-m', 'pytest']:
  args += ['--collect-only']
if args[:2] == ['-m', 'tools.view']:  # A server: on a free port, stopped by Ctrl-C (its way out) once it serves.
  import signal, socket
  with socket.socket() as probe:
    probe.bind(('127.0.0.1', 0))
    port = probe.getsockname()[1]
  proc = subprocess.Popen([{python!r}] + args + ['--port', str(port)], stdout=subprocess.PIPE, text=True)
  for line in proc.stdout:
    print(line, end='')
    if line.startswith('viewing '):
      proc.send_signal(signal.SIGINT)
  status = proc.wait()
  status = 0 if status == 128 + signal.SIGINT else status
else:
  status = subprocess.call([{python!r}] + args)
with open({log!r}, 'a') as f:
  f.write(json.dumps({{'argv': sys.argv[1:], 'status': status}}) + '\\n')
sys.exit(status)
'''


def runnable(block: str) -> str:
  """The block without its install steps (`a && b` chains keep their other steps)."""
  lines = []
  for line in block.splitlines():
    steps = [s for s in line.split(' && ') if not INSTALL_STEP.match(s.strip())]
    lines.append(' && '.join(steps))
  return '\n'.join(lines) + '\n'


def called(block: str) -> set:
  """The scripts / modules a block runs with python ('train.py', 'tools.tables', 'pytest', ...)."""
  return set(re.findall(r'\bpython (?:-m )?([\w./]+)', block))


@pytest.fixture(scope='module')
def sandbox(tmp_path_factory):
  """(repository copy, PATH with the shim first, call log)."""
  root = tmp_path_factory.mktemp('readme')
  repo = root / 'repo'
  shutil.copytree(ROOT, repo, ignore=shutil.ignore_patterns('.git', 'out', 'data', '.venv', '__pycache__',
                                                          '.pytest_cache'))
  if SHARED_SCENES['capture'].is_dir():
    (repo / 'photos').mkdir()
    for name in CAPTURE_PHOTOS:
      shutil.copyfile(SHARED_SCENES['capture'] / 'images' / name, repo / 'photos' / name)
  log = root / 'calls.jsonl'
  (root / 'bin').mkdir()
  for name in ('python', 'python3'):
    shim = root / 'bin' / name
    shim.write_text(SHIM.format(python=sys.executable, tiny=TINY, data=DATA, log=str(log)))
    shim.chmod(0o755)
  return repo, f"{root / 'bin'}{os.pathsep}{os.environ['PATH']}", log


def test_the_readme_has_its_command_blocks():
  blocks = bash_blocks(README)
  assert len(blocks) >= 5
  assert {'train.py', 'eval.py', 'render.py', 'tools.tables', 'pytest'} <= set().union(*map(called, blocks))
  assert any(name.startswith('docs/') for name, _ in BLOCKS)  # The docs' blocks are run too.


@pytest.mark.slow
@pytest.mark.parametrize('index,block', BLOCKS, ids=[name for name, _ in BLOCKS])
def test_readme_block_runs_as_written(index, block, sandbox):
  missing = [str(path) for name, path in SHARED_SCENES.items() if re.search(rf'\b{name}', block) and
             not path.is_dir()]
  if missing:
    pytest.skip(f'block {index} needs shared scenes that are absent: {missing}')
  if 'tools.capture' in called(block) and importlib.util.find_spec('pycolmap') is None:
    pytest.skip(f'block {index} runs tools.capture, which needs pycolmap (pip install -r requirements-capture.txt)')
  repo, path, log = sandbox
  log.write_text('')
  env = dict(os.environ, PATH=path, JAX_COMPILATION_CACHE_DIR=JAX_CACHE,
             JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0', **LOOP_VARIABLES)
  proc = subprocess.run(['bash', '-e', '-c', runnable(block)], cwd=repo, env=env, capture_output=True, text=True,
                        timeout=600, check=False)
  calls = [json.loads(line) for line in log.read_text().splitlines()]
  report = f'block {index}:\n{block}\nstdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}'
  assert proc.returncode == 0 and all(c['status'] == 0 for c in calls), report
  ran = {c['argv'][1] if c['argv'][0] == '-m' else c['argv'][0] for c in calls}
  assert ran == called(block), report


def test_ci_runs_the_readme_test_command_word_for_word_then_the_slow_tests():
  readme_tests = next(line for block in bash_blocks(README) for line in block.splitlines()
                      if line.endswith('python -m pytest -q'))
  commands = [line for line in (ROOT / '.ci' / 'run').read_text().splitlines()
              if line.strip() and not line.startswith(('#', 'set ', 'cd '))]
  assert commands == [readme_tests, 'python -m pytest -q -m slow']
