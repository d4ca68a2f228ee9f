"""Structure-from-motion with pycolmap (the only module that imports it; its API changed twice in 2025, so the
version is pinned in requirements-capture.txt): SIFT features on the CPU, sequential or exhaustive matching,
incremental mapping into every model it finds. The project's own reader (internal/datasets/colmap_model.py) reads
the models it writes.
"""

import dataclasses
import os
import shutil
import sqlite3
import time
import warnings
from typing import List

from internal.run import disk_full
from tools.capture import CaptureError

PINNED = '4.2.1'
INSTALL = 'pip install -r requirements-capture.txt'
CAMERA_MODES = ('single', 'per_folder', 'per_image')
MATCHING = ('sequential', 'exhaustive')
SEED = 0
# Incremental mapping starts from a randomly chosen pair and is not repeatable across threads: on 12 of the cup's
# photos 4 runs in 24 grew a model of 3 images instead of all 12 (two at once on 2 cores, same seed). A model that
# leaves images out is mapped again with the next seeds, and the attempt that registers the most is kept. The pairs'
# geometric verification (RANSAC) is seeded with SEED: unseeded, it verified other pairs in each run, and on 8 of the
# cup's photos at 200 pixels about one run in five registered 2 of them in all three mapping attempts.
MAPPING_ATTEMPTS = 3
VERIFIED = 2  # two_view_geometries.config from this value up: a geometry was verified (COLMAP's enum).
# Incremental mapping that finds no pair to start from halves its minimum matches, then its minimum angle, and tries
# again, twice ('Relaxing the initialization constraints' in its log).
INIT_RELAXATIONS = 2
# Disk space structure-from-motion may take, checked before it starts: its library aborts the process on a full
# disk. An image: SIFT's at most 8192 features of 152 bytes in the database, and its 2D points (24 bytes each) in
# each of the MAPPING_ATTEMPTS models kept at once; a matched pair: its matches and verified inliers, 8 bytes each,
# for 2000 of each (a pair that overlaps well); the database's write-ahead log. The cup's 77 photos at 800 pixels
# took 26 MB of database, 4.4 MB of model and 4 MB of log, a sixth of this bound.
IMAGE_BYTES = 8192 * (152 + 24 * MAPPING_ATTEMPTS)
PAIR_BYTES = 2 * 2000 * 8
LOG_BYTES = 8 << 20
SEQUENTIAL_OVERLAP = 10  # Neighbours each image is matched with in sequential matching (pycolmap's default).


def require_pycolmap():
  """The pycolmap module; CaptureError saying how to install it when it is missing."""
  try:
    import pycolmap  # pylint: disable=import-outside-toplevel  (an optional extra, needed by this tool only)
  except ImportError as err:
    raise CaptureError(f'tools.capture needs pycolmap (structure-from-motion, CPU wheels on PyPI): {INSTALL} '
                       f'(pycolmap=={PINNED})') from err
  if pycolmap.__version__ != PINNED:
    warnings.warn(f'pycolmap {pycolmap.__version__} is installed; tools.capture is tested with {PINNED} (its API '
                  f'changes between versions): {INSTALL}')
  return pycolmap


@dataclasses.dataclass
class Result:
  """The models' folders and registered images, largest first, the seconds each stage took, the mapping runs."""
  models: List[str]
  sizes: List[int]
  seconds: dict
  mapping_attempts: int = 1


def reconstruct(database: str, image_dir: str, models_dir: str, camera_mode: str, camera_model: str,
                matching: str) -> Result:
  """Features, matches and incremental mapping of the images in image_dir; the models go to models_dir/<k>/."""
  pycolmap = require_pycolmap()
  pycolmap.logging.minloglevel = 3  # Fatal only: the tool prints its own progress and errors.
  pycolmap.set_random_seed(SEED)
  seconds, start = {}, time.perf_counter()

  def done(stage: str) -> None:
    nonlocal start
    seconds[stage], start = time.perf_counter() - start, time.perf_counter()
    print(f'  {stage}: {seconds[stage]:.0f} s', flush=True)

  reader = pycolmap.ImageReaderOptions()
  reader.camera_model = camera_model
  mode = getattr(pycolmap.CameraMode, camera_mode.upper())
  pycolmap.extract_features(database, image_dir, camera_mode=mode, reader_options=reader, device=pycolmap.Device.cpu)
  done('extraction')
  match = pycolmap.match_sequential if matching == 'sequential' else pycolmap.match_exhaustive
  verification = pycolmap.TwoViewGeometryOptions()
  verification.ransac.random_seed = SEED  # Its default (-1) draws a new seed each run: the verified pairs varied.
  match(database, verification_options=verification, device=pycolmap.Device.cpu)
  done('matching')
  sizes, attempts = _map_best(pycolmap, database, image_dir, models_dir)
  done('mapping')
  return Result([os.path.join(models_dir, str(k)) for k in range(len(sizes))], sizes, seconds, attempts)


def space_needed(n_images: int, matching: str) -> int:
  """Bytes structure-from-motion may write for n_images with matching (at most, see IMAGE_BYTES)."""
  pairs = n_images * (n_images - 1) // 2 if matching == 'exhaustive' else n_images * SEQUENTIAL_OVERLAP
  return n_images * IMAGE_BYTES + pairs * PAIR_BYTES + LOG_BYTES


def require_space(database: str, n_images: int, matching: str) -> None:
  """DiskFullError (exit status 4) when the disk holding database has less free space than space_needed."""
  needed, free = space_needed(n_images, matching), shutil.disk_usage(os.path.dirname(database)).free
  if free < needed:
    raise disk_full.DiskFullError(
        f'no space left on the device for structure-from-motion in {os.path.dirname(database)!r}: its database and '
        f'models ({database!r}, ...) may take {needed / 2**20:.0f} MiB for {n_images} images ({matching} matching) '
        f'and {free / 2**20:.0f} MiB are free; free disk space and run the same command again')


def _map_best(pycolmap, database: str, image_dir: str, models_dir: str) -> tuple:
  """(registered images per model, largest first, in models_dir/<k>/; mapping runs): incremental mapping with
  SEED, again with the next seeds while the largest model leaves images out, keeping the run that registers most."""
  n_images, best = image_count(database), None
  for attempt in range(MAPPING_ATTEMPTS):
    folder = os.path.join(models_dir, f'attempt_{attempt}')
    os.makedirs(folder)
    pycolmap.set_random_seed(SEED + attempt)
    options = pycolmap.IncrementalPipelineOptions()
    options.min_model_size = 2  # Keep small models: the report names them, and the error tells 2 from none.
    options.random_seed = SEED + attempt
    models = pycolmap.incremental_mapping(database, image_dir, folder, options=options)
    ranked = sorted(models, key=lambda k: (-models[k].num_reg_images(), k))
    sizes = [models[k].num_reg_images() for k in ranked]
    if best is None or sizes[:1] > best[1][:1]:
      best = (folder, sizes, ranked)
    if sizes and sizes[0] == n_images:
      break
  for k, key in enumerate(best[2]):
    os.rename(os.path.join(best[0], str(key)), os.path.join(models_dir, str(k)))
  for other in range(attempt + 1):
    shutil.rmtree(os.path.join(models_dir, f'attempt_{other}'))
  return best[1], attempt + 1


def image_count(database: str) -> int:
  """The images in a COLMAP database."""
  return int(_scalar(database, 'SELECT COUNT(*) FROM images'))


def _scalar(database: str, query: str, *args):
  """The one value a query returns from a COLMAP database, opened read-only."""
  with sqlite3.connect(f'file:{database}?mode=ro', uri=True) as connection:
    return connection.execute(query, args).fetchone()[0]


def initial_pair_needs() -> tuple:
  """(verified matches, degrees between the views) that the pair a model starts from needs at the least: pycolmap's
  defaults after INIT_RELAXATIONS halvings of each."""
  mapper = require_pycolmap().IncrementalPipelineOptions().mapper
  return mapper.init_min_num_inliers >> INIT_RELAXATIONS, mapper.init_min_tri_angle / 2 ** INIT_RELAXATIONS


def best_pair(database: str) -> int:
  """The most verified matches any two images share in the database (0 without any)."""
  return int(_scalar(database, 'SELECT MAX(rows) FROM two_view_geometries WHERE config >= ?', VERIFIED) or 0)
