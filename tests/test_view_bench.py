"""bench/viewer_fps.py on a tiny model at random weights: each size's frames timed after a compiling one, frames per
second the inverse of the median, the 'auto' moving size read off the full size's speed."""

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
    assert len(size['seconds']) == 2 and size['fps'] == round(1. / size['median_seconds'], 3)
    assert size['median_seconds'] == round(float(np.median(size['seconds'])), 4)
  assert record['seconds_per_ray'] == sizes['full']['median_seconds'] / 320
  assert 12 <= record['auto_moving_rows'] <= 16 and record['run'] == '(random weights)'
