"""tools.capture end to end on 12 of the cup's real photos at reduced size: every photo registered, the cameras
against the cup's independent poses (poses_bounds.npy) after a similarity alignment, the capture as the loader
reads it, the report and picture; then each input error, one line and nothing lost."""

import contextlib
import importlib.util
import io
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from conftest import SHARED_DATA
from internal import config_loader
from internal.cameras import algebra
from internal.datasets import colmap_model, load_dataset
from internal.datasets import capture as capture_loader
from tools.capture import CaptureError, __main__ as capture, bench, output, photos, pipeline, poses, sfm

CUP = SHARED_DATA / 'colmap' / 'cup'
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
needs_cup = pytest.mark.skipif(not CUP.is_dir(), reason=f'the shared cup capture is absent: {CUP} does not exist')
needs_pycolmap = pytest.mark.skipif(importlib.util.find_spec('pycolmap') is None,
                                    reason='pycolmap is not installed (pip install -r requirements-capture.txt)')
PHOTOS = [f'{i}.jpg' for i in range(1, 13)]  # One pass along the cup's arc.
SIDEWAYS = '3.jpg'  # Stored turned, with the EXIF orientation that turns it back (as phones save portrait shots).
TURNED = '7.jpg'    # Stored turned without a tag: 600 x 800, a camera of its own.
# OpenCV camera axes of TURNED against its upright original: PIL's rotate(90) turns the picture counter-clockwise.
TURNED_AXES = np.array([[0., -1., 0.], [1., 0., 0.], [0., 0., 1.]])
MAX_SIZE = 400  # Structure-from-motion at half size (the photos are 800 x 600).
# Bounds on the pose errors at this size (three runs measured: median rotation 0.55-0.70 degrees, largest 1.2-1.5;
# median position 0.6% of the camera distance, largest 2.2%); runs are not bit-identical.
MEDIAN_DEGREES, MAX_DEGREES, MEDIAN_POSITION, MAX_POSITION = 1.5, 3., .02, .05
SHIPPED_FOCAL = 589.03  # poses_bounds.npy's focal length (the first image's) at 800 x 600.


def _cup_photos(folder) -> None:
  """The 12 photos, SIDEWAYS and TURNED stored turned, plus a byte-for-byte copy and a file that is no photo."""
  folder.mkdir()
  for name in PHOTOS:
    shutil.copyfile(CUP / 'images' / name, folder / name)
  with Image.open(CUP / 'images' / SIDEWAYS) as image:
    exif = Image.Exif()
    exif[photos.ORIENTATION_TAG] = 6  # Shown after turning 90 degrees clockwise.
    image.rotate(90, expand=True).save(folder / SIDEWAYS, quality=95, exif=exif)
  with Image.open(CUP / 'images' / TURNED) as image:
    image.rotate(90, expand=True).save(folder / TURNED, quality=95)
  shutil.copyfile(CUP / 'images' / '5.jpg', folder / 'copy_of_5.jpg')
  (folder / 'notes.txt').write_text('not a photo')


@pytest.fixture(scope='module')
def cup_capture(tmp_path_factory):
  """(capture folder, its report, the printed output) of the tool on the 12 photos."""
  if not CUP.is_dir():
    pytest.skip(f'the shared cup capture is absent: {CUP} does not exist')
  if importlib.util.find_spec('pycolmap') is None:
    pytest.skip('pycolmap is not installed (pip install -r requirements-capture.txt)')
  root = tmp_path_factory.mktemp('capture')
  _cup_photos(root / 'photos')
  printed = io.StringIO()
  with contextlib.redirect_stdout(printed), pytest.warns(UserWarning) as warned:
    assert capture.main([str(root / 'photos'), '--out', str(root / 'cup'), '--max_size', str(MAX_SIZE)]) == 0
  with open(root / 'cup' / 'report.json', encoding='utf-8') as f:
    return root / 'cup', json.load(f), printed.getvalue() + ''.join(str(w.message) for w in warned)


def test_every_photo_registers_and_the_cameras_match_the_independent_poses(cup_capture):
  folder, report, _ = cup_capture
  assert (report['photos'], report['registered'], report['unregistered']) == (12, 12, [])
  names, c2w = poses.model_cameras(colmap_model.read_model(str(folder / 'sparse' / '0')))
  reference = poses.llff_cameras(np.load(CUP / 'poses_bounds.npy'))
  reference = reference[[sorted(os.listdir(CUP / 'images')).index(n) for n in names]]
  reference[names.index(TURNED), :, :3] = reference[names.index(TURNED), :, :3] @ TURNED_AXES
  errors = poses.pose_errors(c2w, reference)
  assert np.median(errors['rotation_deg']) < MEDIAN_DEGREES and errors['rotation_deg'].max() < MAX_DEGREES, errors
  assert np.median(errors['position']) < MEDIAN_POSITION and errors['position'].max() < MAX_POSITION, errors


def test_cameras_are_scaled_back_to_the_full_photos(cup_capture):
  folder, report, _ = cup_capture
  model = colmap_model.read_model(str(folder / 'sparse' / '0'))
  sizes = {i.name: (model.cameras[i.camera_id].width, model.cameras[i.camera_id].height) for i in model.images.values()}
  assert sizes == {name: (600, 800) if name == TURNED else (800, 600) for name in PHOTOS}
  assert report['sfm_long_side'] == MAX_SIZE and report['camera_mode'] == 'per_folder'  # Two sizes, two cameras.
  for camera in model.cameras.values():
    assert camera.params[0] == pytest.approx(SHIPPED_FOCAL, rel=.05)
    assert camera.params[1:3] == pytest.approx([camera.width / 2, camera.height / 2])


def _reprojection_errors(model) -> np.ndarray:
  """Pixels between every 2D observation of a 3D point and the point projected by its image's camera (COLMAP's
  SIMPLE_RADIAL: f, cx, cy, k; x = f u (1 + k |u|^2) + c of u the normalized camera coordinates)."""
  found = []
  for image in model.images.values():
    seen = image.points2d[image.points2d['point3d_id'] >= 0]
    xyz = np.stack([model.points[int(i)].xyz for i in seen['point3d_id']])
    in_camera = xyz @ algebra.quaternion_to_rotation(image.qvec).T + image.tvec
    normalized = in_camera[:, :2] / in_camera[:, 2:]
    camera = model.cameras[image.camera_id]
    assert camera.model == 'SIMPLE_RADIAL'
    f, cx, cy, k = camera.params
    projected = f * normalized * (1. + k * (normalized ** 2).sum(-1, keepdims=True)) + [cx, cy]
    found.append(np.linalg.norm(projected - np.stack([seen['x'], seen['y']], -1), axis=-1))
  return np.concatenate(found)


def test_the_points_project_onto_their_observations_at_the_full_size(cup_capture):
  folder, report, _ = cup_capture
  errors = _reprojection_errors(colmap_model.read_model(str(folder / 'sparse' / '0')))
  assert len(errors) > 1000
  scale = 800 / MAX_SIZE  # Structure-from-motion's pixels are this many of the full photos'.
  assert np.mean(errors) < 2 * scale * report['reprojection_error_px'] and np.percentile(errors, 99) < 8 * scale


def test_inputs_are_checked_and_written_upright(cup_capture):
  folder, report, printed = cup_capture
  assert report['rotated'] == [SIDEWAYS] and report['duplicates'] == {'copy_of_5.jpg': '5.jpg'}
  assert report['skipped'] == ['notes.txt'] and 'copy_of_5.jpg (= 5.jpg)' in printed and 'notes.txt' in printed
  with Image.open(folder / 'images' / SIDEWAYS) as written, Image.open(CUP / 'images' / SIDEWAYS) as original:
    assert written.size == (800, 600)
    assert np.abs(np.asarray(written, float) - np.asarray(original, float)).mean() < 3.
  assert (folder / 'images' / '1.jpg').read_bytes() == (CUP / 'images' / '1.jpg').read_bytes()  # Copied as is.
  for name in PHOTOS:
    with Image.open(folder / 'images' / name) as full:
      for k in photos.FACTORS:
        with Image.open(folder / f'images_{k}' / name) as small:
          assert small.size == (full.width // k, full.height // k)


def test_the_loader_reads_the_capture_with_the_reported_views(cup_capture):
  folder, report, _ = cup_capture
  config = config_loader.load_config([os.path.join(REPO, pipeline.CONFIG)], [f"Config.data_dir = '{folder}'"])
  test = load_dataset('test', config)
  found = capture_loader.read_capture(config)
  assert [found.names[i] for i in test.ids] == report['views']['test']
  assert report['rig'] == ('forward' if found.forward else 'inward') and test.images.shape[1:3] == (150, 200)
  # 12 images hold 2 test views: the command binds the learning curve's views to those two.
  assert report['next'] == (f'python train.py --gin_configs={pipeline.CONFIG} --gin_bindings="Config.data_dir = '
                            f"'{folder}'\" \"Config.curve_test_ids = [0, 1]\" \"Config.checkpoint_dir = 'out/cup'\"")


def test_the_printed_command_fits_the_capture():
  assert pipeline.bindings('c', 4, 77) == ["Config.data_dir = 'c'"]
  assert pipeline.bindings('c', 8, 20) == ["Config.data_dir = 'c'", 'Config.factor = 8', 'Config.render_factor = 8']
  assert pipeline.bindings('c', 4, 5) == ["Config.data_dir = 'c'", 'Config.curve_test_ids = [0]']  # 1 test view.
  assert pipeline.bindings('c', 4, 3) == ["Config.data_dir = 'c'", 'Config.n_input_views = 2',
                                         'Config.curve_test_ids = [0]']


def test_report_summary_and_picture(cup_capture):
  folder, report, printed = cup_capture
  assert f'{folder}: 12 of 12 images registered' in printed and f'next: {report["next"]}' in printed
  assert set(report['seconds']) == {'inputs', 'extraction', 'matching', 'mapping', 'total'}
  assert ('mapping run' in printed) == (report['mapping_attempts'] > 1) and report['mapping_attempts'] in (1, 2, 3)
  assert report['points'] > 100 and 0. < report['reprojection_error_px'] < 1.
  assert all({'check', 'images', 'message'} == set(f) for f in report['flags'])
  with Image.open(folder / 'cameras.png') as picture:
    assert picture.format == 'PNG' and picture.width > 1000


def test_every_file_written_is_recorded(cup_capture):
  folder = cup_capture[0]
  with open(folder / output.MANIFEST, encoding='utf-8') as f:
    recorded = set(f.read().split('\n')) - {''}
  written = {os.path.relpath(os.path.join(d, n), folder) for d, _, files in os.walk(folder) for n in files}
  trees = {r for r in recorded if r.endswith('/')}
  assert trees == {'sfm/'}  # Structure-from-motion's folder, whose files pycolmap names: removed whole.
  assert {w for w in written if not w.startswith('sfm/')} - {output.MANIFEST} == recorded - {
      r for r in recorded if r.startswith('sfm/')}


def _photos(folder, names) -> str:
  """A folder holding the cup's photos of these names."""
  folder.mkdir()
  for name in names:
    shutil.copyfile(CUP / 'images' / name, folder / name)
  return str(folder)


def test_without_pycolmap_the_error_says_how_to_install_it(tmp_path, monkeypatch):
  monkeypatch.setitem(sys.modules, 'pycolmap', None)  # `import pycolmap` raises ImportError.
  with pytest.raises(CaptureError, match=r'needs pycolmap .*pip install -r requirements-capture.txt'):
    capture.main([str(tmp_path), '--out', str(tmp_path / 'capture')])
  assert not (tmp_path / 'capture').exists()


@needs_cup
@needs_pycolmap
def test_photos_too_far_apart_have_no_initial_pair(tmp_path):
  source = _photos(tmp_path / 'photos', ['1.jpg', '40.jpg', '70.jpg'])
  with pytest.raises(CaptureError, match=r'no initial pair: .*3 images .*verified matches.*; from a few photos '
                                         r'structure-from-motion often finds no pair .*Config.train_view_ids'):
    capture.main([source, '--out', str(tmp_path / 'capture'), '--max_size', '200'])


@needs_cup
@needs_pycolmap
def test_fewer_than_three_registered_images_is_an_error(tmp_path, monkeypatch):
  source = _photos(tmp_path / 'photos', ['1.jpg', '2.jpg', '3.jpg'])
  monkeypatch.setattr(sfm, 'reconstruct', lambda *args: sfm.Result(['model'], [2], {}))  # A model of 2 images.
  with pytest.raises(CaptureError, match=r'only 2 of the 3 images registered \(at least 3 are needed\)'):
    capture.main([source, '--out', str(tmp_path / 'capture'), '--max_size', '200'])


@needs_cup
@needs_pycolmap
def test_two_photos_are_too_few(tmp_path):
  source = _photos(tmp_path / 'photos', ['1.jpg', '2.jpg'])
  with pytest.raises(CaptureError, match=r'holds 2 distinct images; structure-from-motion needs at least 3'):
    capture.main([source, '--out', str(tmp_path / 'capture')])
  assert not (tmp_path / 'capture').exists()


@needs_pycolmap
def test_unreadable_photos_are_named_before_anything_is_written(tmp_path):
  (tmp_path / 'photos').mkdir()
  Image.new('RGB', (64, 48)).save(tmp_path / 'photos' / 'a.jpg')
  (tmp_path / 'photos' / 'b.jpg').write_bytes((tmp_path / 'photos' / 'a.jpg').read_bytes()[:100])
  (tmp_path / 'photos' / 'c.png').write_text('not an image')
  with pytest.raises(CaptureError, match=r'cannot read 2 of the 3 photos .*b\.jpg .*c\.png'):
    capture.main([str(tmp_path / 'photos'), '--out', str(tmp_path / 'capture')])
  assert not (tmp_path / 'capture').exists()


@needs_pycolmap
def test_an_existing_output_is_refused_in_one_line_with_status_2(tmp_path):
  (tmp_path / 'photos').mkdir()
  (tmp_path / 'capture').mkdir()
  (tmp_path / 'capture' / 'mine.txt').write_text('kept')
  proc = subprocess.run([sys.executable, '-m', 'tools.capture', str(tmp_path / 'photos'), '--out',
                         str(tmp_path / 'capture')], cwd=REPO, capture_output=True, text=True, check=False)
  assert proc.returncode == 2 and proc.stdout == '', proc.stderr
  assert proc.stderr.strip().splitlines() == [
      f"error: --out '{tmp_path / 'capture'}' exists; choose a new folder, or add --overwrite to replace what "
      'tools.capture wrote there (nothing else is removed)']
  assert (tmp_path / 'capture' / 'mine.txt').read_text() == 'kept'


@needs_pycolmap
def test_a_video_that_cannot_be_decoded_is_an_error(tmp_path):
  (tmp_path / 'clip.mp4').write_bytes(b'\0' * 1000)
  with pytest.raises(CaptureError, match=r"cannot decode the video .*clip\.mp4"):
    capture.main([str(tmp_path / 'clip.mp4'), '--out', str(tmp_path / 'capture')])


@needs_pycolmap
def test_a_missing_input_or_a_single_photo_is_an_error(tmp_path):
  with pytest.raises(CaptureError, match=r'does not exist; expected a folder of photos or a video file'):
    capture.main([str(tmp_path / 'nothing'), '--out', str(tmp_path / 'capture')])
  Image.new('RGB', (8, 8)).save(tmp_path / 'one.jpg')
  with pytest.raises(CaptureError, match=r'is one photo; expected the folder holding the photos'):
    capture.main([str(tmp_path / 'one.jpg'), '--out', str(tmp_path / 'capture')])


@needs_cup
@needs_pycolmap
def test_the_benchmark_writes_its_results_with_the_pose_errors(tmp_path):
  source = _photos(tmp_path / 'photos', PHOTOS)
  rows = np.load(CUP / 'poses_bounds.npy')[[sorted(os.listdir(CUP / 'images')).index(n) for n in sorted(PHOTOS)]]
  np.save(tmp_path / 'poses_bounds.npy', rows)
  printed = io.StringIO()
  with contextlib.redirect_stdout(printed):
    bench.main([source, '--reference', str(tmp_path / 'poses_bounds.npy'), '--out', str(tmp_path / 'r' / 'cup.json'),
                '--work', str(tmp_path / 'work'), '--matching', 'sequential', '--max_size', str(MAX_SIZE)])
  with open(tmp_path / 'r' / 'cup.json', encoding='utf-8') as f:
    run = json.load(f)['runs'][0]
  assert run['capture'] == str(tmp_path / 'work' / f'{tmp_path.name}_sequential') and run['registered'] == 12
  assert run['median_rotation_deg'] < MEDIAN_DEGREES and run['median_position'] < MEDIAN_POSITION
  assert set(run['seconds_per_photo']) == {'extraction', 'matching', 'mapping'}
  assert run['targets_met']['all_registered'] and '| sequential | 12 of 12 |' in (tmp_path / 'r' / 'cup.md').read_text()
  np.save(tmp_path / 'poses_bounds.npy', rows[:5])
  with pytest.raises(CaptureError, match=r'has 5 cameras for the 12 photos'):
    bench.errors(run['capture'], str(tmp_path / 'poses_bounds.npy'), source)
