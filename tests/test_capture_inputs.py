"""tools.capture on what users bring besides a folder of photos at 800 x 600: a few photos chosen out of a folder
(--photos) under a path with spaces, other letters and a quote, whose printed command bash gives back word for word;
and 960 x 540 video frames (no side a multiple of 8), which train with the recommended config both as the tool
writes them and as COLMAP alone leaves them (images/ and sparse/0 only: the loader crops what fills no block)."""

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import warnings

import gin
import numpy as np
import pytest
from PIL import Image

from conftest import JAX_CACHE
from internal import cli
from internal import config_loader
from internal.datasets import load_dataset
from internal.evaluation import learning_curve
from test_capture import CUP, REPO, _photos, needs_cup, needs_pycolmap
from test_capture_parts import _bash_words, _video
from tools.capture import __main__ as capture, pipeline

pytestmark = [needs_cup, needs_pycolmap, pytest.mark.filterwarnings('ignore:os.fork:RuntimeWarning')]
ODD_PATH = "dir with spaces/日本語 ü/it's"
FRAMES = 12  # Cup photos 1 to 12 as the frames of a 960 x 540 video.


def _printed_command(printed: str) -> list:
  """The words bash makes of the train.py command the tool printed ('next: ...')."""
  line = next(l for l in printed.splitlines() if l.startswith('next: '))[len('next: '):]
  return _bash_words(line)


def test_a_few_photos_chosen_from_a_folder_make_a_capture_of_those_alone(tmp_path):
  chosen = ['2.jpg', '4.jpg', '6.jpg', '8.jpg', '10.jpg', '12.jpg']
  (tmp_path / ODD_PATH).mkdir(parents=True)
  source = _photos(tmp_path / ODD_PATH / 'photos', [f'{i}.jpg' for i in range(1, 13)])
  out = tmp_path / ODD_PATH / 'capture'
  printed = io.StringIO()
  with contextlib.redirect_stdout(printed):
    assert capture.main([source, '--photos', *chosen[::-1], '--out', str(out), '--max_size', '200']) == 0
  with open(out / 'report.json', encoding='utf-8') as f:
    report = json.load(f)
  assert sorted(os.listdir(out / 'images')) == sorted(chosen) and report['photos'] == 6
  assert report['flags'][0]['check'] == 'few_photos' and 'Config.train_view_ids' in report['flags'][0]['message']
  words = _printed_command(printed.getvalue())
  assert words[:3] == ['python', 'train.py', f'--gin_configs={pipeline.CONFIG}'] and words[3].startswith('--gin_')
  gin.clear_config()
  config = config_loader.load_config([os.path.join(REPO, pipeline.CONFIG)],
                                     [words[3].split('=', 1)[1]] + words[4:])
  assert config.data_dir == str(out)
  train = load_dataset('train', config)  # The capture loader reads the capture as training does.
  assert len(train.ids) == 3 and train.images.shape[1:] == (150, 200, 3)


def _video_960x540(path) -> None:
  """The cup's photos 1 to FRAMES, each scaled to 960 x 720 and its middle 540 rows kept, as a video."""
  frames = []
  for i in range(1, FRAMES + 1):
    with Image.open(CUP / 'images' / f'{i}.jpg') as image:
      frames.append(np.asarray(image.resize((960, 720), Image.Resampling.LANCZOS).crop((0, 90, 960, 630))))
  _video(path, frames)


@pytest.fixture(scope='module')
def video_capture(tmp_path_factory):
  """(the capture the tool made of the 960 x 540 video, the words of the train.py command it printed)."""
  root = tmp_path_factory.mktemp('video')
  _video_960x540(root / 'cup.mp4')
  printed = io.StringIO()
  with contextlib.redirect_stdout(printed):
    assert capture.main([str(root / 'cup.mp4'), '--out', str(root / 'capture'), '--frames', str(FRAMES),
                         '--max_size', '480']) == 0
  return root / 'capture', _printed_command(printed.getvalue())


def test_the_tools_960x540_copies_are_what_the_loader_makes_of_the_full_frames(video_capture, tmp_path):
  folder, words = video_capture
  with Image.open(next((folder / 'images').iterdir())) as frame:
    assert frame.size == (960, 540)
  only_colmap = tmp_path / 'colmap_only'
  for name in ('images', 'sparse'):
    shutil.copytree(folder / name, only_colmap / name)
  curves = []
  for data_dir in (folder, only_colmap):  # At the learning curve's factor 8: images_8/, else images/ cropped.
    gin.clear_config()
    config = config_loader.load_config([os.path.join(REPO, pipeline.CONFIG)], [words[3].split('=', 1)[1]] + words[4:]
                                       + [f'Config.data_dir = {str(data_dir)!r}'])
    with warnings.catch_warnings(record=True) as warned:
      warnings.simplefilter('always')
      curves.append(learning_curve.load_views(config, load_dataset('test', config)).images)
    assert [str(w.message) for w in warned if 'cropped' in str(w.message)] == ([] if data_dir == folder else [
        f"{str(only_colmap / 'images')!r}: images cropped from 960 x 540 to 960 x 536 pixels (the last rows and "
        "columns, which fill no 8 x 8 block) to average them down by 8 (Config.downsample_mode = 'area'); the "
        'cameras are unchanged'])
  assert curves[0].shape[1:] == (67, 120, 3) and curves[0].shape == curves[1].shape
  assert np.abs(curves[0] - curves[1]).mean() < .01  # JPEG's noise: both are block means of the same pixels.


def test_a_960x540_capture_from_colmap_alone_trains_with_the_recommended_config(video_capture, tmp_path):
  folder, words = video_capture
  for name in ('images', 'sparse'):
    shutil.copytree(folder / name, tmp_path / 'capture' / name)
  bindings = [f"Config.data_dir = {str(tmp_path / 'capture')!r}", f"Config.checkpoint_dir = {str(tmp_path / 'run')!r}",
              'Config.max_steps = 2', 'Config.curve_every = 1', 'Config.batch_size = 64']
  env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=JAX_CACHE, JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS='0')
  env.pop(cli.DEBUG_ENV, None)
  done = subprocess.run([sys.executable, *words[1:], *bindings], cwd=REPO, env=env, capture_output=True, text=True,
                        timeout=600, check=False)
  assert done.returncode == 0, done.stderr[-3000:]
  assert done.stderr.count('images cropped from 960 x 540 to 960 x 536 pixels') == 1, done.stderr[-3000:]
  with open(tmp_path / 'run' / 'learning_curve.csv', encoding='utf-8') as f:
    assert len(f.read().splitlines()) == 3  # The header, steps 1 and 2.
