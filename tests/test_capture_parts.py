"""tools/capture's parts without structure-from-motion: pose errors, the order check, the output folder's records,
photo checks, camera scaling and video frames (tests/test_capture.py runs the whole tool on real photos)."""

import ast
import os
import pathlib
import shutil
import sqlite3
import subprocess

import gin
import numpy as np
import pytest
from PIL import Image, ImageFilter

from conftest import SHARED_DATA
from internal import cli
from internal import config_loader
from internal.cameras import algebra, alignment
from internal.datasets import colmap_model
from tools.capture import CaptureError, bench, model, output, photos, pipeline, poses, report, sfm
from tools.capture import video

ROOT = pathlib.Path(__file__).resolve().parents[1]
CUP = SHARED_DATA / 'colmap' / 'cup'


def _rotation(axis, degrees: float) -> np.ndarray:
  """Rodrigues' rotation about axis [3] by degrees."""
  axis = np.asarray(axis, float) / np.linalg.norm(axis)
  k = np.array([[0., -axis[2], axis[1]], [axis[2], 0., -axis[0]], [-axis[1], axis[0], 0.]])
  angle = np.radians(degrees)
  return np.eye(3) + np.sin(angle) * k + (1. - np.cos(angle)) * k @ k


def _arc(n: int = 20, radius: float = 2., degrees: float = 120.) -> np.ndarray:
  """[n, 3, 4] OpenCV cameras on an arc about +z at height 0.5, looking at the origin, in arc order."""
  angles = np.radians(np.linspace(0., degrees, n))
  centres = np.stack([radius * np.cos(angles), radius * np.sin(angles), np.full(n, .5)], -1)
  return np.stack([algebra.viewmatrix(-c, np.array([0., 0., -1.]), c) for c in centres])


def test_similarity_recovers_a_known_one_and_the_errors_of_moved_cameras_are_zero():
  reference = _arc()
  rotation, scale, shift = _rotation([1., 2., 3.], 40.), 3.7, np.array([1., -2., .5])
  moved = np.concatenate([rotation @ reference[:, :, :3], (scale * reference[:, :, 3] @ rotation.T + shift)[..., None]],
                         -1)
  fit = alignment.fit(reference, moved)
  np.testing.assert_allclose(fit.scale, scale, rtol=1e-10)
  np.testing.assert_allclose(fit.rotation, rotation, atol=1e-10)
  found = poses.pose_errors(moved, reference)
  assert found['rotation_deg'].max() < 1e-5 and found['position'].max() < 1e-10


def test_pose_errors_measure_a_camera_turned_and_one_moved():
  reference = _arc(40)
  wrong = reference.copy()
  wrong[5, :, :3] = wrong[5, :, :3] @ _rotation([0., 1., 0.], 3.)    # Turned 3 degrees about its own y axis.
  wrong[20, :, 3] += np.array([0., 0., .2])                            # Moved by 0.2.
  found = poses.pose_errors(wrong, reference)
  distance = np.hypot(2., .5)  # From the point the cameras look at, (0, 0, 0).
  assert alignment.camera_distance(reference) == pytest.approx(distance)
  assert found['rotation_deg'][5] == pytest.approx(3., abs=.1) and np.median(found['rotation_deg']) < .1
  assert found['position'][20] == pytest.approx(.2 / distance, abs=.005) and np.median(found['position']) < .005


def test_rotation_angles_of_known_turns():
  turns = np.stack([_rotation([0., 0., 1.], d) for d in (0., 30., 90., 180.)])
  np.testing.assert_allclose(np.degrees(alignment.rotation_angle(turns)), [0., 30., 90., 180.], atol=1e-6)


@pytest.mark.skipif(not CUP.is_dir(), reason=f'the shared cup capture is absent: {CUP} does not exist')
def test_llff_cameras_equal_the_colmap_model_they_were_made_from():
  names, c2w = poses.model_cameras(colmap_model.read_model(str(CUP / 'sparse' / '0')))
  reference = poses.llff_cameras(np.load(CUP / 'poses_bounds.npy'))
  assert names == sorted(os.listdir(CUP / 'images'))
  np.testing.assert_allclose(reference, c2w, atol=1e-9)


@pytest.mark.skipif(not (SHARED_DATA / 'dtu' / 'dtu_scan24').is_dir(), reason='the shared DTU scan is absent')
def test_dtu_reference_cameras_are_the_calibrations_centres_and_rotations():
  path = SHARED_DATA / 'dtu' / 'dtu_scan24' / 'cameras_sphere.npz'
  c2w = bench.reference_cameras(str(path), ['000000.png', '000013.png'], '')
  for camera, index in zip(c2w, (0, 13)):
    projection = np.load(path)[f'world_mat_{index}'][:3].astype(np.float64)
    np.testing.assert_allclose(camera[:, 3], -np.linalg.solve(projection[:, :3], projection[:, 3]), rtol=1e-9)
    viewing = projection[2, :3] / np.linalg.norm(projection[2, :3])  # P's third row: the optical axis (z) in world.
    np.testing.assert_allclose(camera[:, 2], viewing * np.sign(np.linalg.det(projection[:, :3])), atol=1e-9)
    np.testing.assert_allclose(camera[:, :3].T @ camera[:, :3], np.eye(3), atol=1e-9)


def test_order_check_passes_one_sweep_and_flags_a_turn_and_a_jump():
  arc = _arc(30)
  names = [f'{i}.jpg' for i in range(30)]
  assert report.order_problems(arc, False, names) == {'jumps': [], 'turns': []}
  assert report.order_problems(arc[::-1], False, names) == {'jumps': [], 'turns': []}  # Either way round.
  folded = np.concatenate([arc[:20], arc[18:8:-1]])  # Out to the 20th camera, then back over 10 of them.
  assert report.order_problems(folded, False, names) == {'jumps': [], 'turns': ['at 19.jpg']}
  passes = np.concatenate([arc[::2], arc[1::2]])  # Two passes: every other camera, then the rest.
  assert report.order_problems(passes, False, names) == {'jumps': ['14.jpg -> 15.jpg'], 'turns': []}


def test_flags_name_few_point_images_and_images_left_out():
  fields = {'unregistered': ['9.jpg'], 'photos': 10, 'left_in_other_models': [], 'models': [9],
            'views': {'train': ['1.jpg', '5.jpg'], 'test': ['0.jpg', '3.jpg']}}
  counts = {f'{i}.jpg': 400 for i in range(9)} | {'3.jpg': 60}
  found = report.flags(fields, {'jumps': [], 'turns': []}, counts, video=False)
  assert [f['check'] for f in found] == ['unregistered', 'few_points']
  assert found[1]['images'] == ['3.jpg'] and '3.jpg (60)' in found[1]['message']
  assert 'among the default views: 3.jpg (test)' in found[1]['message']


def test_overwrite_removes_only_recorded_files(tmp_path):
  root = tmp_path / 'capture'
  first = output.Output(str(root), overwrite=False)
  for rel in ('images/a.jpg', 'sfm/models/0/x.bin', 'report.json'):
    pathlib.Path(first.claim(rel)).write_text('ours')
  (root / 'notes.txt').write_text('the user\'s')
  (root / 'sparse' / '1').mkdir(parents=True)
  with pytest.raises(CaptureError, match='exists; choose a new folder, or add --overwrite'):
    output.Output(str(root), overwrite=False)
  output.Output(str(root), overwrite=True)
  # Ours gone, the user's kept; the new run's manifest begun.
  assert sorted(p.name for p in root.iterdir()) == [output.MANIFEST, 'notes.txt', 'sparse']
  (root / 'images').mkdir()
  (root / 'images' / 'mine.jpg').write_text('the user\'s')
  with pytest.raises(CaptureError, match=r"images' was not written by tools.capture"):
    output.Output(str(root), overwrite=True)
  assert (root / 'images' / 'mine.jpg').read_text() == 'the user\'s'


def test_a_recorded_folder_goes_whole_and_an_unfinished_capture_is_replaced_without_overwrite(tmp_path):
  root = tmp_path / 'capture'
  first = output.Output(str(root), overwrite=False)
  sfm_dir = pathlib.Path(first.claim_folder('sfm'))
  pathlib.Path(first.claim('sfm/database.db')).write_text('ours')
  (sfm_dir / 'database.db-wal').write_text('the library\'s')  # Files the tool never named, as pycolmap writes.
  (sfm_dir / 'models' / 'attempt_0' / '0').mkdir(parents=True)
  (sfm_dir / 'models' / 'attempt_0' / '0' / 'images.bin').write_text('the library\'s')
  assert output.unfinished(str(root))  # Stopped before its report: the same command takes it over.
  output.Output(str(root), overwrite=False)
  assert sorted(p.name for p in root.iterdir()) == [output.MANIFEST]
  pathlib.Path(output.Output(str(root), overwrite=False).claim(output.REPORT)).write_text('{}')
  assert not output.unfinished(str(root))
  with pytest.raises(CaptureError, match='exists; choose a new folder, or add --overwrite'):
    output.Output(str(root), overwrite=False)


def test_an_input_inside_the_output_is_refused(tmp_path):
  (tmp_path / 'c' / 'images').mkdir(parents=True)
  for source, out in ((tmp_path / 'c' / 'images', tmp_path / 'c'), (tmp_path / 'c', tmp_path / 'c'),
                      (tmp_path / 'c' / 'images', tmp_path / 'link')):
    if not os.path.lexists(tmp_path / 'link'):
      os.symlink(tmp_path / 'c', tmp_path / 'link')
    with pytest.raises(CaptureError, match=r'is inside --out .*choose a --out outside it'):
      output.refuse_input_inside(str(source), str(out))
  output.refuse_input_inside(str(tmp_path / 'c'), str(tmp_path / 'c' / 'capture'))  # A capture beside the photos.
  output.refuse_input_inside(str(tmp_path / 'c'), str(tmp_path / 'c2'))


def test_natural_order_and_photo_listing(tmp_path):
  for name in ('10.jpg', '2.JPG', '1.png', 'b.txt', '.hidden.jpg'):
    (tmp_path / name).write_bytes(b'')
  (tmp_path / 'sub').mkdir()
  assert photos.list_photos(str(tmp_path)) == (['1.png', '2.JPG', '10.jpg'], ['b.txt'])
  (tmp_path / 'empty').mkdir()
  (tmp_path / 'empty' / 'a.heic').write_bytes(b'')
  with pytest.raises(CaptureError, match=r"no JPEG or PNG photos in .*empty.*not read.*a.heic.*convert them"):
    photos.list_photos(str(tmp_path / 'empty'))


def test_the_tools_own_files_are_never_photos_and_photos_picks_a_few(tmp_path):
  for name in ('1.jpg', '2.jpg', '3.jpg', 'cameras.png'):
    (tmp_path / name).write_bytes(b'')
  (tmp_path / output.MANIFEST).write_text('cameras.png\nreport.json\nimages/1.jpg\n')  # A capture made here before.
  with pytest.warns(UserWarning, match=r'left out of .*, written there by tools.capture: cameras.png'):
    assert photos.list_photos(str(tmp_path)) == (['1.jpg', '2.jpg', '3.jpg'], [])
  (tmp_path / output.MANIFEST).unlink()
  assert photos.list_photos(str(tmp_path), ['3.jpg', '1.jpg', '3.jpg']) == (['1.jpg', '3.jpg'], [])
  with pytest.raises(CaptureError, match=r"--photos: '4.jpg', 'b.txt' not among the JPEG/PNG photos of .*e.g. 1.jpg"):
    photos.list_photos(str(tmp_path), ['1.jpg', '4.jpg', 'b.txt'])


def _photo(path, size=(64, 48), seed=0, orientation=None):
  """Writes a random-noise JPEG of size (width, height), stored with an EXIF orientation if given."""
  pixels = np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
  exif = Image.Exif()
  if orientation:
    exif[photos.ORIENTATION_TAG] = orientation
  Image.fromarray(pixels).save(path, quality=95, exif=exif)


def test_inspect_applies_orientation_finds_duplicates_and_names_unreadable_photos(tmp_path):
  _photo(tmp_path / '1.jpg')
  _photo(tmp_path / '2.jpg', seed=1, orientation=6)  # Stored sideways: 64 x 48 stored, 48 x 64 upright.
  (tmp_path / '3.jpg').write_bytes((tmp_path / '1.jpg').read_bytes())
  found, duplicates = photos.inspect(str(tmp_path), ['1.jpg', '2.jpg', '3.jpg'])
  assert [(p.name, p.width, p.height, p.orientation) for p in found] == [('1.jpg', 64, 48, 1), ('2.jpg', 48, 64, 6)]
  assert duplicates == {'3.jpg': '1.jpg'}
  assert photos.camera_folders(found, per_image=False) == {'1.jpg': 'camera1', '2.jpg': 'camera2'}
  assert photos.camera_folders(found[:1], per_image=False) == {'1.jpg': ''}
  (tmp_path / '4.jpg').write_bytes((tmp_path / '2.jpg').read_bytes()[:300])  # Cut short.
  (tmp_path / '5.jpg').write_text('not an image')
  with pytest.raises(CaptureError, match=r'cannot read 2 of the 5 photos .*4\.jpg .*5\.jpg'):
    photos.inspect(str(tmp_path), ['1.jpg', '2.jpg', '3.jpg', '4.jpg', '5.jpg'])


def test_written_images_are_upright_and_downsampled_to_the_loaders_sizes(tmp_path):
  _photo(tmp_path / 'a.jpg', size=(90, 61), orientation=8)
  found, _ = photos.inspect(str(tmp_path), ['a.jpg'])
  out = output.Output(str(tmp_path / 'capture'), overwrite=False)
  photos.write_images(found, out)
  photos.write_downsampled(['a.jpg'], out)
  with Image.open(tmp_path / 'a.jpg') as stored, Image.open(tmp_path / 'capture' / 'images' / 'a.jpg') as upright:
    assert upright.size == (61, 90) and upright.getexif().get(photos.ORIENTATION_TAG) is None
    turned = np.asarray(stored.transpose(Image.Transpose.ROTATE_90), float)  # Orientation 8: turn 90 degrees back.
    assert np.abs(np.asarray(upright, float) - turned).mean() < 12.  # JPEG noise on random pixels.
  for k in photos.FACTORS:
    with Image.open(tmp_path / 'capture' / f'images_{k}' / 'a.jpg') as small:
      assert small.size == (61 // k, 90 // k)
  assert photos.sfm_size(found[0], 30) == (20, 30) and photos.sfm_size(found[0], 1000) == (61, 90)


def test_downsampled_copies_are_block_means_of_the_top_left_whole_blocks(tmp_path):
  pixels = np.random.default_rng(3).integers(0, 256, (61, 90, 3), dtype=np.uint8)  # No side a multiple of 8.
  out = output.Output(str(tmp_path / 'capture'), overwrite=False)
  Image.fromarray(pixels).save(out.claim('images/a.png'))  # PNG: lossless, so exact.
  photos.write_downsampled(['a.png'], out)
  for k in photos.FACTORS:
    h, w = 61 // k, 90 // k
    blocks = pixels[:h * k, :w * k].reshape(h, k, w, k, 3).astype(float).mean((1, 3))  # Pixel (i, j): k i, k j on.
    with Image.open(tmp_path / 'capture' / f'images_{k}' / 'a.png') as small:
      assert np.abs(np.asarray(small, float) - blocks).max() <= 1.  # Pillow's fixed-point rounding to uint8.


def _bash_words(line: str) -> list:
  """The words bash makes of a command line."""
  done = subprocess.run(['bash', '-c', f'printf "%s\\0" {line}'], capture_output=True, check=True)
  return done.stdout.decode('utf-8').split('\0')[:-1]


def test_the_printed_command_gives_its_words_back_from_bash_for_any_folder_name():
  out = "/data/dir with spaces/日本語 ü/it's/a \"b\" $HOME `x` \\ !"
  line = pipeline.next_command(out, pipeline.bindings(out, 4, 20))
  words = _bash_words(line[len('python train.py '):])
  assert words[:2] == [f'--gin_configs={pipeline.CONFIG}', '--gin_bindings=' + words[1].split('=', 1)[1]]
  bindings = [words[1].split('=', 1)[1]] + words[2:]
  gin.clear_config()
  parsed = config_loader.load_config([os.path.join(pipeline.REPO, pipeline.CONFIG)], bindings)
  assert parsed.data_dir == out and parsed.checkpoint_dir == 'out/' + os.path.basename(out)


def test_structure_from_motion_is_refused_in_one_line_with_status_4_without_the_space_it_may_take(tmp_path,
                                                                                               monkeypatch, capsys):
  assert sfm.space_needed(77, 'exhaustive') > 26 * 2**20 + 4.4 * 2**20 + 4 * 2**20  # Above the cup's measured use.
  assert sfm.space_needed(10, 'sequential') < sfm.space_needed(10, 'exhaustive') + 10 * 9 * sfm.PAIR_BYTES
  database = str(tmp_path / 'database.db')
  sfm.require_space(database, 3, 'exhaustive')  # This disk has room.
  usage = shutil.disk_usage(tmp_path)
  monkeypatch.setattr(shutil, 'disk_usage', lambda path: usage._replace(free=sfm.space_needed(3, 'exhaustive') // 2))
  monkeypatch.delenv(cli.DEBUG_ENV, raising=False)
  assert cli.run(lambda: sfm.require_space(database, 3, 'exhaustive')) == cli.DISK_FULL_STATUS
  assert capsys.readouterr().err == (
      f"error: no space left on the device for structure-from-motion in {str(tmp_path)!r}: its database and models "
      f"({database!r}, ...) may take 13 MiB for 3 images (exhaustive matching) and 7 MiB are free; free disk space "
      'and run the same command again\n')
  assert not os.listdir(tmp_path)


def test_scaled_camera_scales_focal_lengths_and_principal_point_only():
  camera = colmap_model.Camera(1, 'OPENCV', 400, 300, np.array([300., 310., 200., 150., .1, -.02, .001, .002]))
  big = model.scaled_camera(camera, 1600, 1200)
  np.testing.assert_allclose(big.params, [1200., 1240., 800., 600., .1, -.02, .001, .002])
  simple = model.scaled_camera(colmap_model.Camera(2, 'SIMPLE_RADIAL', 400, 300, np.array([300., 200., 150., .1])),
                               800, 600)
  np.testing.assert_allclose(simple.params, [600., 400., 300., .1])
  # A point's projection u = f x / z + c at the small size, scaled, is its projection by the scaled camera.
  x, z = .3, 2.
  assert (300. * x / z + 200.) * 4 == pytest.approx(big.params[0] * x / z + big.params[2])


def _video(path, frames):
  """Writes frames [N, H, W, 3] uint8 as an mp4 with the ffmpeg that imageio-ffmpeg ships."""
  import imageio_ffmpeg  # pylint: disable=import-outside-toplevel
  writer = imageio_ffmpeg.write_frames(str(path), frames[0].shape[1::-1], fps=4, macro_block_size=1, quality=9)
  writer.send(None)
  for frame in frames:
    writer.send(np.ascontiguousarray(frame))
  writer.close()


@pytest.mark.filterwarnings('ignore:os.fork:RuntimeWarning')  # ffmpeg runs as a subprocess of this jax process.
def test_video_frames_are_the_sharpest_of_each_window(tmp_path):
  rng = np.random.default_rng(0)
  sharp = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(6)]
  blurred = [np.asarray(Image.fromarray(f).filter(ImageFilter.GaussianBlur(2))) for f in sharp]
  # Windows of 3 frames: the sharp frame is first, second, third, ... in turn.
  frames = [(sharp[w] if i == w % 3 else blurred[w]) for w in range(6) for i in range(3)]
  _video(tmp_path / 'clip.mp4', frames)
  names = video.extract_frames(str(tmp_path / 'clip.mp4'), 6, output.Output(str(tmp_path / 'capture'), False))
  assert names == [f'frame_{3 * w + w % 3:05d}.jpg' for w in range(6)]
  assert video.sharpness(sharp[0]) > 3 * video.sharpness(blurred[0])


def test_a_video_that_cannot_be_decoded_is_one_error(tmp_path):
  (tmp_path / 'clip.mp4').write_bytes(b'\0' * 1000)
  with pytest.raises(CaptureError, match=r"cannot decode the video .*clip\.mp4"):
    video.extract_frames(str(tmp_path / 'clip.mp4'), 10, output.Output(str(tmp_path / 'capture'), False))


def test_only_the_structure_from_motion_module_imports_pycolmap():
  importers = []
  for path in ROOT.rglob('*.py'):
    if '.venv' in path.parts or 'out' in path.parts:
      continue
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
      names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
               [node.module] if isinstance(node, ast.ImportFrom) and node.module else [])
      if any(n.split('.')[0] == 'pycolmap' for n in names):
        importers.append(str(path.relative_to(ROOT)))
  assert sorted(set(importers)) == ['tools/capture/sfm.py']


class _Model:
  def __init__(self, n):
    self.n = n

  def num_reg_images(self):
    return self.n


class _Mapper:
  """Stands in for pycolmap's mapping: the models each seed grows (their folders written as pycolmap does)."""

  def __init__(self, sizes_by_seed):
    self.sizes_by_seed, self.seeds = sizes_by_seed, []

  def set_random_seed(self, seed):
    self.seeds.append(seed)

  class IncrementalPipelineOptions:
    min_model_size = random_seed = None

  def incremental_mapping(self, database, image_dir, folder, options):
    del database, image_dir
    models = dict(enumerate(_Model(n) for n in self.sizes_by_seed[options.random_seed]))
    for k, m in models.items():
      os.makedirs(os.path.join(folder, str(k)))
      pathlib.Path(folder, str(k), 'size').write_text(str(m.n))
    return models


def _database(path, n_images):
  with sqlite3.connect(path) as connection:
    connection.execute('CREATE TABLE images (image_id INTEGER)')
    connection.executemany('INSERT INTO images VALUES (?)', [(i,) for i in range(n_images)])
  return str(path)


@pytest.mark.parametrize('sizes_by_seed, kept, runs', [
    ({0: [12, 3]}, [12, 3], 1),                          # Every image in the first model: mapped once.
    ({0: [3, 2, 2], 1: [12, 2]}, [12, 2], 2),             # A fragment, then all: the second run kept.
    ({0: [2], 1: [9, 3], 2: [5]}, [9, 3], 3),             # Never all: the largest of the three runs kept.
    ({0: [], 1: [], 2: []}, [], 3),                       # No initial pair in any run.
])
def test_mapping_runs_again_while_images_are_left_out_and_keeps_the_largest(tmp_path, sizes_by_seed, kept, runs):
  mapper = _Mapper(sizes_by_seed)
  sizes, attempts = sfm._map_best(mapper, _database(tmp_path / 'db', 12), 'images', str(tmp_path / 'models'))
  assert (sizes, attempts, mapper.seeds) == (kept, runs, list(range(runs)))
  assert sorted(os.listdir(tmp_path / 'models')) == [str(k) for k in range(len(kept))]   # No run left behind.
  assert [int((tmp_path / 'models' / str(k) / 'size').read_text()) for k in range(len(kept))] == kept
