"""The input photos: found, checked (readable, EXIF orientation, duplicates, sizes per camera) and written as the
capture's `images/`, the copies structure-from-motion runs on (no larger than --max_size) and `images_2/4/8`.

Photos are the JPEG and PNG files directly in the folder, in natural name order (2.jpg before 10.jpg): the order
they were taken in, which the report's order check uses. A photo stored rotated (EXIF orientation, as phones save
portrait shots) is written upright, without the tag, so that COLMAP and the loader see the same pixels. Photos
share a camera when they share their upright size and the EXIF camera and focal length (one camera per group in
structure-from-motion: COLMAP leaves an image of another size out of a shared camera without an error).
"""

import dataclasses
import hashlib
import os
import re
import shutil
import warnings
from typing import Dict, List, Optional, Tuple

from PIL import Image, ImageOps

from tools.capture import CaptureError, output as output_lib

PHOTO_EXTENSIONS = ('.jpg', '.jpeg', '.png')
ORIENTATION_TAG = 274  # EXIF Orientation: 1 upright, 2-8 mirrored and / or rotated.
CAMERA_TAGS = (271, 272)  # EXIF Make and Model.
EXIF_IFD, FOCAL_LENGTH_TAG = 0x8769, 37386
FACTORS = (2, 4, 8)  # images_<k>/: the loader's downsampled copies, each (height // k, width // k), cropped.
JPEG_QUALITY = 95


@dataclasses.dataclass(frozen=True)
class Photo:
  """One input photo: its file name, source path, upright size in pixels, EXIF orientation and camera group."""
  name: str
  source: str
  width: int
  height: int
  orientation: int
  camera: Tuple


def natural_key(name: str) -> list:
  """Sort key that orders the numbers inside names by value ('2.jpg' before '10.jpg')."""
  return [int(part) if part.isdigit() else part.lower() for part in re.split(r'(\d+)', name)]


def list_photos(folder: str, chosen: Optional[List[str]] = None) -> Tuple[List[str], List[str]]:
  """(JPEG/PNG file names of folder in natural order, other file names): sub-folders, hidden files and what
  tools.capture wrote there (its manifest's files) ignored; chosen: only these photos (--photos), others ignored."""
  files = [n for n in os.listdir(folder) if not n.startswith('.') and os.path.isfile(os.path.join(folder, n))]
  written = sorted(set(files) & set(output_lib.recorded(folder)), key=natural_key)
  if written:
    warnings.warn(f'left out of {folder!r}, written there by tools.capture: {", ".join(written)}')
  names = sorted(set(files) - set(written), key=natural_key)
  photos = [n for n in names if n.lower().endswith(PHOTO_EXTENSIONS)]
  others = [n for n in names if not n.lower().endswith(PHOTO_EXTENSIONS)]
  if chosen:
    missing = [n for n in dict.fromkeys(chosen) if n not in photos]
    if missing:
      raise CaptureError(f'--photos: {", ".join(map(repr, missing))} not among the JPEG/PNG photos of {folder!r} '
                         f'(expected file names in it, e.g. {", ".join(photos[:3]) or "none there"})')
    return [n for n in photos if n in chosen], []
  if not photos:
    found = f'; it holds {len(others)} other files ({", ".join(others[:3])}...): convert them to JPEG' if others else ''
    raise CaptureError(f'no JPEG or PNG photos in {folder!r} (sub-folders are not read){found}')
  return photos, others


def _camera_key(image: Image.Image, width: int, height: int) -> Tuple:
  """The camera group of an upright photo: its size and its EXIF make, model and focal length (when present)."""
  exif = image.getexif()
  focal = exif.get_ifd(EXIF_IFD).get(FOCAL_LENGTH_TAG)
  return (width, height) + tuple(str(exif.get(tag, '')).strip() for tag in CAMERA_TAGS) + (
      str(float(focal)) if focal else '',)


def inspect(folder: str, names: List[str]) -> Tuple[List[Photo], Dict[str, str]]:
  """(the readable photos without duplicates, {duplicate: the earlier photo it repeats}); CaptureError naming
  every photo that cannot be decoded."""
  photos, duplicates, unreadable, seen = [], {}, [], {}
  for name in names:
    path = os.path.join(folder, name)
    with open(path, 'rb') as f:
      digest = hashlib.sha256(f.read()).hexdigest()
    if digest in seen:
      duplicates[name] = seen[digest]
      continue
    seen[digest] = name
    try:
      with Image.open(path) as image:
        image.load()
        orientation = int(image.getexif().get(ORIENTATION_TAG, 1))
        size = image.size if orientation < 5 else image.size[::-1]  # 5-8 swap width and height.
        photos.append(Photo(name, path, size[0], size[1], orientation, _camera_key(image, *size)))
    except (OSError, SyntaxError, ValueError) as err:
      unreadable.append(f'{name} ({str(err).splitlines()[0][:80]})')
  if unreadable:
    raise CaptureError(f'cannot read {len(unreadable)} of the {len(names)} photos in {folder!r}: '
                       f'{"; ".join(unreadable[:5])}{"; ..." if len(unreadable) > 5 else ""}; remove or replace them')
  return photos, duplicates


def _upright(path: str) -> Image.Image:
  """The photo at path with its EXIF orientation applied (and the tag removed)."""
  with Image.open(path) as image:
    return ImageOps.exif_transpose(image)


def _save(image: Image.Image, path: str, exif: Image.Exif) -> None:
  """Writes image as its file name's format: JPEG at high quality with the EXIF given (its camera and focal
  length, which COLMAP reads), or PNG."""
  if path.lower().endswith('.png'):
    image.save(path)
  else:
    image.convert('RGB').save(path, quality=JPEG_QUALITY, exif=exif)


def write_images(photos: List[Photo], output: output_lib.Output) -> None:
  """images/<name> for every photo: the file itself when it is upright, else its upright pixels."""
  for photo in photos:
    path = output.claim(os.path.join('images', photo.name))
    if photo.orientation == 1:
      shutil.copyfile(photo.source, path)
    else:
      upright = _upright(photo.source)
      _save(upright, path, upright.getexif())


def sfm_size(photo: Photo, max_size: int) -> Tuple[int, int]:
  """(width, height) of the photo's structure-from-motion copy: its long side at most max_size."""
  scale = min(1., max_size / max(photo.width, photo.height))
  return max(1, round(photo.width * scale)), max(1, round(photo.height * scale))


def camera_folders(photos: List[Photo], per_image: bool) -> Dict[str, str]:
  """{photo name: the sub-folder of its camera group}: '' for one group (or one camera per image)."""
  groups = list(dict.fromkeys(p.camera for p in photos))
  if per_image or len(groups) == 1:
    return {p.name: '' for p in photos}
  return {p.name: f'camera{groups.index(p.camera) + 1}' for p in photos}


def write_sfm_copies(photos: List[Photo], folders: Dict[str, str], output: output_lib.Output,
                     max_size: int) -> Dict[str, str]:
  """sfm/images/[<camera>/]<name>: the upright photos no larger than max_size; returns {name in sfm/images: name}."""
  names = {}
  for photo in photos:
    rel = os.path.join(folders[photo.name], photo.name)
    path = output.claim(os.path.join('sfm', 'images', rel))
    upright = os.path.join(output.root, 'images', photo.name)
    size = sfm_size(photo, max_size)
    if size == (photo.width, photo.height):
      shutil.copyfile(upright, path)
    else:
      with Image.open(upright) as image:
        _save(image.resize(size, Image.Resampling.LANCZOS), path, image.getexif())
    names[rel.replace(os.sep, '/')] = photo.name
  return names


def write_downsampled(names: List[str], output: output_lib.Output) -> None:
  """images_<k>/<name> for k in FACTORS: the block means of k x k pixels of images/<name>, (height // k, width // k)
  of them; the last rows and columns that fill no block are left out (cropped), as the loader does at a factor
  without a folder, so that pixel (i, j) of images_<k> is k x k pixels from (k i, k j) and the cameras scale by k."""
  for name in names:
    with Image.open(os.path.join(output.root, 'images', name)) as image:
      image.load()
      for k in FACTORS:
        size = (image.width // k, image.height // k)
        small = image.crop((0, 0, k * size[0], k * size[1])).resize(size, Image.Resampling.BOX)
        _save(small, output.claim(os.path.join(f'images_{k}', name)), image.getexif())
