"""Photos or a video -> a capture folder to train on (`make`): the inputs checked, structure-from-motion with
pycolmap, the model scaled to the full photos, the smaller copies, the capture loaded back through the colmap
loader, its report and camera picture. The command line is tools/capture/__main__.py; tools.capture.bench and
tools.capture.few_photos make captures through `make` too.
"""

import dataclasses
import json
import math
import os
import time
from typing import Optional, Sequence
import warnings

import gin
import numpy as np

from internal import atomic
from internal import cli
from internal import config_loader
from internal import configs
from internal.cameras import alignment
from internal.datasets import colmap_model, load_dataset
from internal.datasets import capture as capture_loader
from internal.evaluation import learning_curve
from internal.run import disk_full
from tools.capture import CaptureError, model, output as output_lib, photos, picture, poses, report as report_lib
from tools.capture import sfm, video

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CONFIG = 'configs/mini/capture3_freenerf.gin'  # The config the printed command trains with.
VIEWS, LLFFHOLD = 3, 8  # Its view count and hold-out rule (configs/common/capture.gin).
FACTORS = (4, 8)  # The training image size: the config's factor 4 unless the images stay larger than MAX_TRAIN_SIDE.
MAX_TRAIN_SIDE = 512
MIN_REGISTERED = 3
FEW_PHOTOS = 9  # A capture of this many photos or fewer is a few-photo one: the report and errors say what it risks.
FEW_ADVICE = ('from a few photos structure-from-motion often finds no pair to start from, leaves photos out or places '
              'them degrees off (measured: results/capture/few_photos.md); to train on a few photos, run it on all you '
              'took (many, each overlapping the next) and choose the few with Config.train_view_ids')
# Structure-from-motion copies' long side: on DTU's 1600 x 1200 photos, 800 gave the same cameras as 1600 in a
# quarter of the time (results/capture/README.md).
MAX_SIZE = 800
CURVE_VIEWS = len(configs.Config.curve_test_ids)  # The learning curve's test views (CONFIG keeps the default).


@dataclasses.dataclass(frozen=True)
class Options:
  """What a capture is made of and how: the command's flags (python -m tools.capture --help)."""
  input: str  # A folder of photos, or a video file.
  out: str
  photos: Optional[Sequence[str]] = None  # Structure-from-motion on only these photos of the folder.
  max_size: int = MAX_SIZE
  frames: int = 100
  matching: Optional[str] = None  # sfm.MATCHING; None: sequential for a video, exhaustive for photos.
  camera: str = 'shared'
  camera_model: str = 'SIMPLE_RADIAL'
  overwrite: bool = False

  def __post_init__(self):
    if self.photos and os.path.isfile(self.input):
      raise CaptureError(f'--photos names photos of a folder; {self.input!r} is a file (a video)')
    if self.max_size < 100 or self.frames < MIN_REGISTERED:
      raise CaptureError(f'--max_size {self.max_size} / --frames {self.frames}: expected --max_size >= 100 pixels '
                         f'and --frames >= {MIN_REGISTERED}')


def input_kind(source: str) -> str:
  """'photos' (a folder) or 'video' (a file); CaptureError for a path that is neither."""
  if not os.path.exists(source):
    raise CaptureError(f'{source!r} does not exist; expected a folder of photos or a video file')
  if os.path.isfile(source) and source.lower().endswith(photos.PHOTO_EXTENSIONS):
    raise CaptureError(f'{source!r} is one photo; expected the folder holding the photos, or a video file')
  return 'video' if os.path.isfile(source) else 'photos'


def checked_inputs(source: str, kind: str, folder: str, names: list, skipped: list) -> tuple:
  """(the distinct readable images of folder among names, report fields on the inputs); warns of what is left out."""
  found, duplicates = photos.inspect(folder, names)
  if len(found) < MIN_REGISTERED:
    raise CaptureError(f'{source!r} holds {len(found)} distinct images; structure-from-motion needs at least '
                       f'{MIN_REGISTERED}, and registers them reliably from about 20 overlapping ones')
  if skipped:
    warnings.warn(f'left out of {source!r}, not JPEG or PNG: {report_lib.listed(skipped)}')
  if duplicates:
    warnings.warn('left out, byte-for-byte repeats of an earlier photo: '
                  + report_lib.listed([f'{a} (= {b})' for a, b in duplicates.items()]))
  return found, {'input': cli.relative_paths(os.path.abspath(source)), 'kind': kind, 'photos': len(found),
                 'skipped': skipped, 'duplicates': duplicates, 'rotated': [p.name for p in found if p.orientation != 1]}


def run_sfm(args: Options, found, output, kind: str) -> tuple:
  """(the largest model at full size, report fields): structure-from-motion on the copies, errors if it failed."""
  folders = photos.camera_folders(found, args.camera == 'per_image')
  output.claim_folder('sfm')  # Whole: pycolmap names its own files there (the database's journals, the models).
  names = photos.write_sfm_copies(found, folders, output, args.max_size)
  mode = 'per_image' if args.camera == 'per_image' else 'per_folder' if any(folders.values()) else 'single'
  matching = args.matching or ('sequential' if kind == 'video' else 'exhaustive')
  database = output.claim(os.path.join('sfm', 'database.db'))
  sfm.require_space(database, len(found), matching)
  n_cameras = len(found) if mode == 'per_image' else len(set(folders.values()))
  print(f'structure-from-motion on {len(found)} images ({matching} matching, {n_cameras} camera'
        f'{"s" if n_cameras > 1 else ""}; on 2 cores about a second an image for a hundred, exhaustive matching '
        'growing with their square):', flush=True)
  result = sfm.reconstruct(database, os.path.join(args.out, 'sfm', 'images'), os.path.join(args.out, 'sfm', 'models'),
                           mode, args.camera_model, matching)
  advice = f'; {FEW_ADVICE}' if len(found) <= FEW_PHOTOS else ''
  if not result.models:
    raise CaptureError(f'{no_initial_pair(len(found), sfm.best_pair(database))}{advice}')
  if result.sizes[0] < MIN_REGISTERED:
    raise CaptureError(f'only {result.sizes[0]} of the {len(found)} images registered (at least {MIN_REGISTERED} '
                       f'are needed); take more photos, each overlapping its neighbours by well over half{advice}')
  sized = model.full_size_model(colmap_model.read_model(result.models[0]), names,
                                {p.name: (p.width, p.height) for p in found})
  for name in colmap_model.FILES:
    output.claim(os.path.join('sparse', '0', f'{name}.bin'))
  colmap_model.write_binary(sized, os.path.join(args.out, 'sparse', '0'))
  registered = {i.name for i in sized.images.values()}
  apart = {names[i.name] for m in result.models[1:] for i in colmap_model.read_model(m).images.values()} - registered
  long_side = max(max(photos.sfm_size(p, args.max_size)) for p in found)
  return sized, {'camera_mode': mode, 'camera_model': args.camera_model, 'matching': matching,
                 'max_size': args.max_size, 'sfm_long_side': long_side, 'models': result.sizes,
                 'left_in_other_models': sorted(apart, key=photos.natural_key),
                 'registered': len(registered), 'unregistered': [p.name for p in found if p.name not in registered],
                 'points': len(sized.points), 'reprojection_error_px': model.reprojection_error(sized),
                 'mapping_attempts': result.mapping_attempts, 'seconds': result.seconds}


def no_initial_pair(n_images: int, best: int) -> CaptureError:
  """The error of a reconstruction that found no pair to start from: too few matches, or none of the pairs with
  enough of them made a start (views too close together, matches on one plane or along the line of sight)."""
  matches, degrees = sfm.initial_pair_needs()
  if best < matches:
    return CaptureError(f'no initial pair: no two of the {n_images} images share enough features to start a model '
                        f'(the best pair has {best} verified matches, {matches} are needed even after relaxing the '
                        'start); take more photos, each overlapping its neighbours by well over half')
  return CaptureError(f'no initial pair: images share features ({best} verified matches at best), but no pair of '
                      f'them starts a model: it needs two views at least {degrees:.0f} degrees apart, their matches '
                      'not all on one plane (a table, a wall) nor the camera moved along its line of sight; take '
                      'photos further around the object, each still overlapping its neighbours')


def training_factor(sized) -> int:
  """The factor the printed command trains at: 4 (the config's) unless the images stay over MAX_TRAIN_SIDE."""
  long_side = max(max(c.width, c.height) for c in sized.cameras.values())
  return next((f for f in FACTORS if long_side / f <= MAX_TRAIN_SIDE), FACTORS[-1])


def bindings(out: str, factor: int, n_registered: int) -> list:
  """The gin bindings beside CONFIG for this capture: its folder, and what its size changes (the factor; fewer
  training views, or fewer learning-curve views, when it has too few images for CONFIG's)."""
  n_test = math.ceil(n_registered / LLFFHOLD)  # Every LLFFHOLD-th along the arc, from the first.
  views = min(VIEWS, n_registered - n_test)
  found = [f'Config.data_dir = {out!r}']
  found += [f'Config.factor = {factor}', f'Config.render_factor = {factor}'] if factor != FACTORS[0] else []
  found += [f'Config.n_input_views = {views}'] if views != VIEWS else []
  return found + ([f'Config.curve_test_ids = {list(range(n_test))}'] if n_test < CURVE_VIEWS else [])


def load_back(gin_bindings: list) -> tuple:
  """(Config, the loader's Capture, default views {split: ids}): the capture read, both splits loaded through the
  capture loader and the learning curve's views checked, with the printed command's config."""
  gin.clear_config()  # The tool's own process: the config is parsed once, fresh.
  config = config_loader.load_config([os.path.join(REPO, CONFIG)], gin_bindings)
  load_dataset('train', config)
  test = load_dataset('test', config)
  if config.curve_every:
    learning_curve.curve_positions(config, len(test.ids))
  capture = capture_loader.read_capture(config)
  return config, capture, capture_loader.default_views(capture, config.llffhold, config.n_input_views)


def next_command(out: str, gin_bindings: list) -> str:
  """The train.py command line for the capture (eval.py and render.py take the same flags), quoted for a shell:
  bash gives back the words, whatever the folder's name holds (spaces, quotes, any letters)."""
  run = f"Config.checkpoint_dir = {'out/' + os.path.basename(os.path.normpath(out))!r}"
  return f'python train.py --gin_configs={CONFIG} --gin_bindings=' + cli.quoted(gin_bindings + [run])


def draw_picture(path: str, sized, capture, views: dict, order: list, title: str) -> None:
  """cameras.png: the model's points moved into the loader's frame by the similarity between both camera sets."""
  fit = alignment.fit(poses.model_cameras(sized)[1], capture.camtoworlds)
  xyz = np.stack([p.xyz for p in sized.points.values()]) if sized.points else np.zeros((0, 3))
  rgb = np.stack([p.rgb for p in sized.points.values()]) / 255. if sized.points else np.zeros((0, 3))
  picture.draw(path, capture.camtoworlds, capture.forward, fit.scale * xyz @ fit.rotation.T + fit.shift, rgb,
               capture.names, order, views, title)


def finish(args: Options, sized, report: dict, output) -> dict:
  """Loads the capture back, adds the views, flags, picture and next command to the report; writes images_k."""
  photos.write_downsampled(sorted(i.name for i in sized.images.values()), output)
  factor = training_factor(sized)
  gin_bindings = bindings(args.out, factor, report['registered'])
  _, capture, views = load_back(gin_bindings)
  order = sorted(range(len(capture.names)), key=lambda i: photos.natural_key(capture.names[i]))
  problems = report_lib.order_problems(capture.camtoworlds[order], capture.forward, [capture.names[i] for i in order])
  report.update(out=args.out, rig='forward' if capture.forward else 'inward', factor=factor,
                views={split: [capture.names[i] for i in ids] for split, ids in views.items()},
                observations=model.observations(sized), order=problems, picture=os.path.join(args.out, 'cameras.png'),
                next=next_command(args.out, gin_bindings))
  report['flags'] = report_lib.flags(report, problems, report['observations'], report['kind'] == 'video')
  if report['photos'] <= FEW_PHOTOS:
    report['flags'].insert(0, {'check': 'few_photos', 'images': [], 'message': f'structure-from-motion ran on '
                               f'{report["photos"]} photos only: {FEW_ADVICE}; look at cameras.png'})
  title = (f'{report["registered"]} of {report["photos"]} images registered, {report["points"]} points, '
           f'{report["rig"]} rig')
  draw_picture(output.claim('cameras.png'), sized, capture, views, order, title)
  return report


def build(args: Options, kind: str, found, report: dict, output, start: float) -> dict:
  """Writes the capture into output (images, structure-from-motion, sparse/0, images_k, picture); its report."""
  if kind == 'photos':
    photos.write_images(found, output)
  else:
    names = video.extract_frames(args.input, args.frames, output)
    found, report = checked_inputs(args.input, kind, os.path.join(args.out, 'images'), names, [])
  report['seconds'] = {'inputs': time.perf_counter() - start}
  sized, fields = run_sfm(args, found, output, kind)
  report.update({**fields, 'seconds': {**report['seconds'], **fields['seconds']}})
  return finish(args, sized, report, output)


def disk_full_at(err: OSError, output) -> OSError:
  """The error of a write into output that found the disk full, naming the file written: a copy's or a rename's
  destination, else the error's own file when it is in --out, else the file the tool was writing."""
  where = err.filename2 or err.filename
  inside = where and os.path.realpath(where).startswith(os.path.realpath(output.root) + os.sep)
  return OSError(err.errno, err.strerror, where if inside else output.writing)


def make(options: Options, command: str) -> dict:
  """The capture options describe, made in options.out: its report (also written there as report.json, last)."""
  start = time.perf_counter()
  sfm.require_pycolmap()
  kind = input_kind(options.input)
  output_lib.refuse_input_inside(options.input, options.out)
  output_lib.refuse_existing(options.out, options.overwrite)
  found, report = (checked_inputs(options.input, kind, options.input, *photos.list_photos(options.input,
                                                                                          options.photos))
                   if kind == 'photos' else (None, {}))  # Before writing.
  if output_lib.unfinished(options.out) and not options.overwrite:
    print(f'{options.out}: replacing the unfinished capture there (its run stopped before {output_lib.REPORT})')
  output = output_lib.Output(options.out, options.overwrite)
  try:
    report = build(options, kind, found, report, output, start)
    report['seconds']['total'] = time.perf_counter() - start
    report['command'] = command
    atomic.write_text(output.claim(output_lib.REPORT), json.dumps(report, indent=1))
  except CaptureError as err:
    raise CaptureError(f'{err} (what it wrote stays in {options.out!r}; the tool run again with that --out replaces '
                       'it)') from err
  except OSError as err:
    if disk_full.is_disk_full(err):
      raise disk_full_at(err, output) from err
    raise
  return report
