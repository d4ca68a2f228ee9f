"""bench/viewer_fps.py on a tiny model at random weights: each size's frames timed after a compiling one, frames per
second the inverse of the median, the 'auto' moving size read off the full size's speed; a slow model's larger
frames extrapolated from a small one's seconds per ray."""

import numpy as np

from bench import viewer_fps
from test_checkpoints import TINY


def test_the_benchmark_times_each_size_after_its_compiling_frame(tmp_path):
  run = viewer_fps.random_weights_run(TINY + [f"Config.data_dir = '{tmp_path / 'scene'}'",
                                              'Config.generated_size = (16, 20)'])
  record = viewer_fps.measure(run, viewer_fps.test_view(run, 1.25), 16, 2, 'tiny')
  sizes = record['sizes']
  assert [(s['rows'], s['width']) for s in sizes.values()] == [(4, 5), (8, 10), (16, 20)]
  for size in sizes.values():
    assert len(size['seconds']) == 2 and size['fps'] == round(1. / float(np.median(size['seconds'])), 3)
    assert size['median_seconds'] == round(float(np.median(size['seconds'])), 4)
  assert record['seconds_per_ray'] == sizes['full']['median_seconds'] / 320
  assert 12 <= record['auto_moving_rows'] <= 16 and record['run'] == '(random weights)'


def test_a_slow_model_is_timed_small_and_its_larger_frames_extrapolated_per_ray(tmp_path):
  run = viewer_fps.random_weights_run(TINY + [f"Config.data_dir = '{tmp_path / 'scene'}'",
                                              'Config.generated_size = (16, 20)'])
  record = viewer_fps.measure(run, viewer_fps.test_view(run, 1.25), 64, 1, 'tiny', timed={'1/8': 1 / 8})
  sizes = record['sizes']
  assert list(sizes) == ['1/8', '1/4', '1/2', 'full'] and 'extrapolated' not in sizes['1/8']
  assert record['seconds_per_ray'] == sizes['1/8']['median_seconds'] / 80
  full = sizes['full']
  assert full['extrapolated'] and (full['rows'], full['width']) == (64, 80)
  assert full['median_seconds'] == round(record['seconds_per_ray'] * 64 * 80, 4)
