"""Dispatch on Config.dataset_loader: load_dataset(split, config) and render_path_rays(config)."""

import dataclasses

import numpy as np

from internal.datasets import base, blender, dtu, llff, packed, synthetic

LOADERS = ('dtu', 'llff', 'blender', 'generated', 'packed')


def load_generated(split: str, config, ground_truth: bool = False) -> base.Dataset:
  """Writes the generated scene into Config.data_dir if absent, then loads it through the Blender/LLFF loader.

  The exact depths and object masks are read only when ground_truth is asked (depth metrics, packing).
  """
  rig, scene_dir = config.generated_rig, config.data_dir
  synthetic.ensure_scene(scene_dir, rig, config.generated_seed, config.generated_size)
  if rig == 'object':
    data = blender.load_blender(split, config, scene_dir, 'generated/object', 'first_n', 1)
    scale = 1.
  else:
    data = llff.load_llff(split, config, scene_dir, 'generated/forward')
    scale = 1. / (.75 * llff.read_poses_bounds(scene_dir)[:, 15:17].min())
  if not ground_truth:
    return data
  depths, masks = synthetic.load_ground_truth(scene_dir, rig, split, data.ids, base.load_factor(config, split),
                                              config.downsample_mode)
  return dataclasses.replace(data, depths=(depths * scale).astype(np.float32), object_masks=masks)


def load_dataset(split: str, config, ground_truth: bool = False) -> base.Dataset:
  """Loads split ('train' | 'test') of the scene Config selects, as a Dataset.

  ground_truth: also read the generated scene's exact depths and object masks (a pack holds them either way).
  """
  base.check_split(split)
  base.check_choice('Config.dataset_loader', config.dataset_loader, LOADERS)
  if config.dataset_loader == 'packed':
    return packed.load_packed(split, config)
  if config.dataset_loader == 'dtu':
    return dtu.load_dtu(split, config)
  if config.dataset_loader == 'llff':
    scene = base.scene_dir(config.data_dir, config.llff_scan, 'llff_scan')
    return llff.load_llff(split, config, scene, f'llff/{config.llff_scan}')
  if config.dataset_loader == 'blender':
    scene = base.scene_dir(config.data_dir, config.blender_scene, 'blender_scene')
    return blender.load_blender(split, config, scene, f'blender/{config.blender_scene}', config.blender_split,
                                blender.TEST_STRIDE)
  return load_generated(split, config, ground_truth)


def render_path_rays(config):
  """Rays [F,H,W,...] of the scene's render path (spiral for LLFF/DTU, orbit for object-centric scenes)."""
  base.check_choice('Config.dataset_loader', config.dataset_loader, LOADERS)
  if config.dataset_loader == 'packed':
    return packed.render_path_rays(config)
  if config.dataset_loader == 'dtu':
    return dtu.render_path_rays(config)
  if config.dataset_loader == 'llff':
    return llff.render_path_rays(config, base.scene_dir(config.data_dir, config.llff_scan, 'llff_scan'))
  if config.dataset_loader == 'blender':
    return blender.render_path_rays(config, base.scene_dir(config.data_dir, config.blender_scene, 'blender_scene'))
  synthetic.ensure_scene(config.data_dir, config.generated_rig, config.generated_seed, config.generated_size)
  fn = blender.render_path_rays if config.generated_rig == 'object' else llff.render_path_rays
  return fn(config, config.data_dir)
