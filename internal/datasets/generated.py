"""The generated scene (scene_generator.py) as a loader: written into Config.data_dir if absent, then read through the
Blender layout (object rig, world-space rays) or the LLFF layout (forward rig, NDC rays)."""

import dataclasses

import numpy as np

from internal.datasets import base, blender, llff, scene_generator

# (Config field, its allowed values) of this loader's own settings, checked before any work.
SETTING_CHOICES = (('generated_rig', scene_generator.RIGS),)


def scene(config) -> str:
  """Config.data_dir after writing the generated scene there if it is absent (checked to match otherwise)."""
  scene_generator.ensure_scene(config.data_dir, config.generated_rig, config.generated_seed, config.generated_size)
  return config.data_dir


def load_scene(split: str, config) -> base.Dataset:
  """One split of the generated scene, without its ground truth (see with_ground_truth)."""
  if config.generated_rig == 'object':
    return blender.load_blender(split, config, scene(config), 'generated/object', 'first_n', 1)
  return llff.load_llff(split, config, scene(config), 'generated/forward')


def with_ground_truth(data: base.Dataset, config) -> base.Dataset:
  """data with the exact depths [N,H,W] (in the units of its rays) and object masks [N,H,W] of its views."""
  rig, scene_dir = config.generated_rig, config.data_dir
  scale = 1. if rig == 'object' else 1. / (.75 * llff.read_poses_bounds(scene_dir)[:, 15:17].min())
  depths, masks = scene_generator.load_ground_truth(scene_dir, rig, data.split, data.ids,
                                              base.load_factor(config, data.split), config.downsample_mode)
  return dataclasses.replace(data, depths=(depths * scale).astype(np.float32), object_masks=masks)


MESH_MARGIN = .05  # Of the object rig's box, on each side.


def mesh_bounds(config):
  """[2, 3] the region to mesh of the object rig: the box around its solids with MESH_MARGIN (None: the forward
  rig's NDC rays, meshed in the NDC box)."""
  if config.generated_rig != 'object':
    return None
  box = scene_generator.scene_bounds(scene_generator.read_scene(scene(config)))
  return box + np.array([-1., 1.])[:, None] * MESH_MARGIN * (box[1] - box[0])


def scene_render_path(config):
  """Rays [F,H,W,...] of the render path: an orbit for the object rig, the LLFF spiral for the forward rig."""
  fn = blender.render_path_rays if config.generated_rig == 'object' else llff.render_path_rays
  return fn(config, scene(config))


def is_ndc(config) -> bool:
  """The forward rig's rays are NDC, as LLFF's; the object rig's are world-space, as Blender's."""
  return config.generated_rig == 'forward'


def filed_as(config) -> tuple:
  """(dataset, scene) of its runs: the layout it is written in, scene 'generated_<rig>' (shown, never averaged)."""
  return ('blender' if config.generated_rig == 'object' else 'llff'), f'generated_{config.generated_rig}'


def pack_cameras(config, datasets: dict) -> dict:
  """The pack's camera record, as for a scene of its layout."""
  if config.generated_rig == 'object':
    return blender.camera_record(config, datasets, scene(config))
  return llff.camera_record(config, datasets, scene(config))


def random_pose_cameras(dataset: base.Dataset, config, rng: np.random.Generator):
  """The forward rig's random poses, as an LLFF scene's (llff.random_cameras); None: the object rig has none."""
  if config.generated_rig == 'object':
    return None
  return llff.random_cameras(dataset, config, rng, config.data_dir)
