"""Photos or a video -> a capture folder the capture loader reads: structure-from-motion with pycolmap.

`python -m tools.capture PHOTOS_DIR_OR_VIDEO --out CAPTURE_DIR` (tools/capture/__main__.py). The steps, one module
each: the inputs checked and written as `images/` (photos.py; video.py takes the sharpest frame per window of a
video), structure-from-motion on copies no larger than --max_size (sfm.py, the only module that imports pycolmap),
the largest model scaled back to the full images as `sparse/0` (model.py), the capture loaded back through the
project's loader, `report.json` with the flags it can raise (report.py) and `cameras.png` (picture.py). The output
folder records every file the tool writes (output.py), so that --overwrite replaces only those. poses.py compares
recovered cameras with independent ones after a similarity fit (tests, bench.py, and few_photos.py, which measures
structure-from-motion on a few photos alone against a model of all of them).
"""


class CaptureError(ValueError):
  """Bad input or a reconstruction that failed; the message names the file or setting and what was expected."""
