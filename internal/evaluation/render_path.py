"""Rendering of a scene's camera path with a run's newest checkpoint to frames and videos."""

import importlib.util
import json
import os
import warnings

import jax
import numpy as np
import tqdm

from internal.run import checkpoints
from internal import datasets
from internal.datasets import loader
from internal.evaluation import inference
from internal.run import run_dir as run_dir_lib
from internal.evaluation import vis
from internal import atomic
from internal import progress

VIDEO_FPS = 30
VIDEO_HINT = 'frames only; for mp4 videos: pip install imageio imageio-ffmpeg'
# Written last, after every frame and video: its presence is what makes a render complete.
DONE_FILE = 'render.json'


def output_dir(root: str, step: int) -> str:
  """<root>/path_renders_step_<step>; root is run_dir.outputs_root(config): Config.output_dir or the run directory."""
  return os.path.join(root, f'path_renders_step_{step}')


def is_complete(out_dir: str) -> bool:
  """True when out_dir holds a finished render (frames and videos); an interrupted one lacks DONE_FILE."""
  return os.path.isfile(os.path.join(out_dir, DONE_FILE))


def existing_renders(config) -> bool:
  """True when the run's newest step has complete path renders (an interrupted render is not)."""
  run_dir = run_dir_lib.check_run_dir(config)
  out_dir = output_dir(run_dir_lib.outputs_root(config), checkpoints.latest_step(run_dir))
  return is_complete(out_dir)


def can_write_video() -> bool:
  """True when imageio and its ffmpeg binary package are installed."""
  return all(importlib.util.find_spec(name) is not None for name in ('imageio', 'imageio_ffmpeg'))


def write_video(frames, path: str) -> None:
  """Writes uint8 frames [F, H, W, 3] as an h264 mp4 at VIDEO_FPS."""
  import imageio.v2 as imageio  # Optional dependency, imported only when videos are written.
  with warnings.catch_warnings():
    # The ffmpeg subprocess forks and then execs at once, which JAX's fork warning does not concern.
    warnings.filterwarnings('ignore', message=r'os\.fork\(\) was called', category=RuntimeWarning)
    with imageio.get_writer(path, fps=VIDEO_FPS, codec='libx264', quality=8, macro_block_size=2) as writer:
      for frame in frames:
        writer.append_data(frame)


def render(config) -> str:
  """Renders every frame of the path; returns the output folder.

  Refuses to replace a complete render unless Config.overwrite; the frames of an interrupted one are rendered again.
  """
  run_dir = run_dir_lib.check_run_dir(config)
  path_rays = datasets.render_path_rays(config)
  model, state = checkpoints.restore_model(config, run_dir, jax.tree.map(lambda x: x[0, 0, :8], path_rays))
  step = int(state.step)  # The newest intact checkpoint's.
  out_dir = output_dir(run_dir_lib.outputs_root(config), step)
  if is_complete(out_dir) and not config.overwrite:
    raise FileExistsError(f'{out_dir!r} holds renders of step {step} already; set Config.overwrite = True to '
                          'replace them')
  run_dir_lib.make_output_folder(config, out_dir)
  render_fn = inference.make_render_fn(config, model, state.params, step)
  frames = {'color': [], 'depth': [], 'opacity': []}
  depth_range = None
  num_frames = path_rays.origins.shape[0]
  for f in tqdm.trange(num_frames, unit='frame', **progress.progress_kwargs()):
    rendering = inference.render_image(render_fn, jax.tree.map(lambda x, f=f: x[f], path_rays),
                                       config.render_chunk_size)
    depth_range = depth_range or vis.depth_range(rendering['distance_mean'])
    for name, image in vis.visualize(rendering, depth_range).items():
      vis.save_png(image, os.path.join(out_dir, f'{name}_{f:03d}.png'))
      frames[name].append(vis.to_uint8(image))
  print(f'{num_frames} frames of step {step} in {out_dir!r}')
  videos = []
  if can_write_video():
    scene = loader.filed_as(config)[1]
    for name, images in frames.items():
      videos.append(f'{scene}_{config.expname}_{name}.mp4')
      write_video(np.stack(images), os.path.join(out_dir, videos[-1]))
  else:
    print(VIDEO_HINT)
  atomic.write_text(os.path.join(out_dir, DONE_FILE),
                    json.dumps({'step': step, 'frames': num_frames, 'videos': videos}, indent=1) + '\n')
  return out_dir
