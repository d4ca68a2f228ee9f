"""The table of scene loaders, one record per Config.dataset_loader value, and the dispatch on it.

Validation (near/far rules), evaluation (how a run is filed, NDC depths), results (the dataset names), the
tables (protocol scenes, metric groups), packing and random poses derive what they need from REGISTRY. Adding a
dataset: a loader file and one Loader.of line here (see docs/design.md, 'Adding a dataset').
"""

import dataclasses
from typing import Callable, Dict, Optional, Tuple

import numpy as np

from internal.cameras import caster
from internal.cameras.records import Cameras
from internal.datasets import base, blender, camera_noise, capture, dtu, generated, llff, packed


# Loader fields filled from the loader file's attribute of that name where it has one (see Loader.of).
MODULE_ATTRIBUTES = (('load', 'load_scene'), ('render_path', 'scene_render_path'),
                     ('protocol_scenes', 'PROTOCOL_SCENES'),
                     ('choices', 'SETTING_CHOICES'), ('pack_cameras', 'pack_cameras'),
                     ('random_pose_cameras', 'random_pose_cameras'), ('mesh_bounds', 'mesh_bounds'))


@dataclasses.dataclass(frozen=True)
class Loader:
  """One Config.dataset_loader value: its functions and how the rest of the code treats its scenes."""
  load: Callable                     # (split, config) -> Dataset.
  render_path: Callable              # config -> Rays [F,H,W,...] of the render path.
  # The Config field naming the scene, or config -> the scene's name (None: filed_as names it).
  scene_setting: Optional[object]
  ndc: Callable                      # config -> True: NDC rays (near 0, far 1); False: world rays (near > 0);
                                     # None: the data decides (a pack checks its settings on load).
  protocol_scenes: Tuple[str, ...] = ()  # The protocol's test scenes, over which the tables average.
  # (column label, metric group of evaluation/metric_registry.py) of the columns of its tables.
  table_groups: Tuple[Tuple[str, str], ...] = (('', 'full'),)
  filed_as: Optional[Callable] = None  # config -> (dataset, scene) of its runs in metrics.json and the tables;
                                       # None: (its own name, the scene setting), a dataset of its own.
  ground_truth: Optional[Callable] = None  # (Dataset, config) -> Dataset with exact depths and object masks.
  pack_cameras: Optional[Callable] = None  # (config, {split: Dataset}) -> the pack's camera record; None: unpackable.
  choices: Tuple[Tuple[str, Tuple[str, ...]], ...] = ()  # (Config field, its allowed values) of its own settings.
  # (Dataset, config, rng) -> RegNeRF's random poses as Cameras (in the axes and RaySpace of the dataset's), or
  # None for a scene without them; None: no random poses (depth smoothness is refused).
  random_pose_cameras: Optional[Callable] = None
  mesh_bounds: Optional[Callable] = None  # config -> [2, 3] region of a world-ray scene to mesh, or None: none.

  @classmethod
  def of(cls, module, scene_setting, ndc, **fields) -> 'Loader':
    """The record of a loader file: MODULE_ATTRIBUTES from the module, ndc a constant or config -> bool, fields
    the rest (or overrides)."""
    found = {field: getattr(module, name) for field, name in MODULE_ATTRIBUTES if hasattr(module, name)}
    rule = ndc if callable(ndc) else lambda config: ndc
    return cls(scene_setting=scene_setting, ndc=rule, **{**found, **fields})


def _filed_as_packed(config) -> Tuple[str, str]:
  """A pack's runs are filed as those of the scene it was packed from (its settings are checked on load)."""
  return filed_as(dataclasses.replace(config, dataset_loader=packed.source_loader(config.data_dir)))


REGISTRY: Dict[str, Loader] = {
    'dtu': Loader.of(dtu, 'dtu_scan', False, table_groups=(('object', 'masked'), ('full', 'full'))),
    'llff': Loader.of(llff, 'llff_scan', True),
    'blender': Loader.of(blender, 'blender_scene', False),
    'generated': Loader.of(generated, None, generated.is_ndc, filed_as=generated.filed_as,
                           ground_truth=generated.with_ground_truth),
    'capture': Loader.of(capture, capture.scene_name, capture.is_ndc),
    'packed': Loader.of(packed, None, None, filed_as=_filed_as_packed),
}
LOADERS = tuple(REGISTRY)
# Earlier names of loaders, read as the current ones: gin files, run folders and metrics.json files written before a
# rename keep working (captures were 'colmap', after the file format, while their settings and tools said capture).
RENAMED = {'colmap': 'capture'}
# The allowed values of Config.dataset_loader and of each loader's own settings, checked before any work.
SETTING_CHOICES = (('dataset_loader', LOADERS),) + tuple(c for record in REGISTRY.values() for c in record.choices)
# The dataset names of metrics.json and the tables: the loaders whose runs are filed under their own name.
RESULT_DATASETS = tuple(name for name, record in REGISTRY.items() if record.filed_as is None)


def loader_of(config) -> Loader:
  """The record of Config.dataset_loader; DatasetError when it names no loader."""
  base.check_choice('Config.dataset_loader', config.dataset_loader, LOADERS)
  return REGISTRY[config.dataset_loader]


def load_dataset(split: str, config, ground_truth: bool = False) -> base.Dataset:
  """Loads split ('train' | 'test') of the scene Config selects, as a Dataset.

  ground_truth: also read the exact depths and object masks where the loader has them (a pack holds them
  either way); they are read only when asked (depth metrics, packing).
  """
  base.check_split(split)
  record = loader_of(config)
  data = record.load(split, config)
  if camera_noise.is_on(config):  # Studies of camera refinement: noise on the training cameras only.
    data = camera_noise.perturbed(data, config)
  return record.ground_truth(data, config) if ground_truth and record.ground_truth else data


def render_path_rays(config):
  """Rays [F,H,W,...] of the scene's render path (spiral for LLFF/DTU, orbit for object-centric scenes)."""
  return loader_of(config).render_path(config)


def ndc(config) -> Optional[bool]:
  """True for NDC rays (near/far fixed at 0/1), False for world rays (near > 0), None when the data decides."""
  return loader_of(config).ndc(config)


def filed_as(config) -> Tuple[str, str]:
  """(dataset, scene) naming a run in metrics.json and the tables (a pack reads its source loader)."""
  record = loader_of(config)
  if record.filed_as is not None:
    return record.filed_as(config)
  scene = record.scene_setting
  return config.dataset_loader, scene(config) if callable(scene) else getattr(config, scene)


def pack_arrays(config, datasets: dict) -> dict:
  """The arrays of the pack of Config's scene from its loaded splits {split: Dataset} (see packed.py)."""
  record = loader_of(config)
  if record.pack_cameras is None:
    packable = [name for name, other in REGISTRY.items() if other.pack_cameras]
    raise base.DatasetError(f'Config.dataset_loader = {config.dataset_loader!r} scenes cannot be packed; pack a '
                            f'scene from its source loader, one of {packable}')
  return packed.pack_arrays(config, datasets, record.pack_cameras(config, datasets))


def mesh_bounds(config) -> Optional[np.ndarray]:
  """[2, 3] the scene's own region to mesh: the NDC box for NDC rays, else its loader's (None: it has none)."""
  record = loader_of(config)
  if record.ndc(config):
    return np.array(caster.NDC_BOX)
  return record.mesh_bounds(config) if record.mesh_bounds else None


def random_pose_cameras(dataset: base.Dataset, config, rng) -> Cameras:
  """RegNeRF's random poses of the training scene as Cameras in its own axes and RaySpace, drawn with rng by its
  loader.

  ValueError naming the settings when the scene has none (the loaders with random poses listed).
  """
  hook = loader_of(config).random_pose_cameras
  found = hook(dataset, config, rng) if hook else None
  if found is None:
    having = [name for name, record in REGISTRY.items() if record.random_pose_cameras]
    raise ValueError(f'Config.depth_tvnorm_loss_mult / depth_tvnorm_decay: random poses exist for scenes of '
                     f'Config.dataset_loader in {having} only; this Config.dataset_loader = '
                     f'{config.dataset_loader!r} scene has none')
  return found
