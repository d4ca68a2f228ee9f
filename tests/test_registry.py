"""The two registries: scene loaders (internal/datasets/loader.py) and metrics (internal/evaluation/metric_registry.py).

The lists derived from them are compared with the hand-written lists they replaced.
"""

import dataclasses
import pathlib
from types import SimpleNamespace

import numpy as np
import pytest

from internal import configs
from internal.configs import Config
from internal.datasets import DatasetError, loader
from internal.evaluation import camera_evaluation, depth_metrics, metric_registry, metrics, results
from tools import tables
from lab.study import export as study_export
from lab.study import spec as study_spec

ROOT = pathlib.Path(__file__).resolve().parents[1]

IMAGE = ('psnr', 'ssim', 'lpips', 'avg_error')
MASKED = ('psnr_masked', 'ssim_masked', 'lpips_masked', 'avg_error_masked')
DEPTH = ('depth_mae', 'depth_within_1pct', 'depth_within_5pct')
PSEUDO = ('pseudo_depth_mae', 'pseudo_depth_within_1pct', 'pseudo_depth_within_5pct')
SFM = ('sfm_depth_mae', 'sfm_depth_within_1pct', 'sfm_depth_within_5pct')
CAMERAS = ('camera_rotation_deg', 'camera_translation', 'camera_rotation_deg_unaligned',
           'camera_translation_unaligned', 'test_pose_rotation_deg', 'test_pose_translation')


def _written_metrics(tmp_path, monkeypatch) -> set:
  """Every key the evaluation's scorers write for one view: image metrics with a mask, exact, pseudo and SfM
  depths."""
  rng = np.random.default_rng(0)
  gt, pred = rng.random((8, 8, 3)), rng.random((8, 8, 3))
  keys = set(metrics.image_metrics(pred, gt, lambda a, b: .1, mask=np.ones_like(gt)))
  depth = rng.uniform(1., 2., (1, 8, 8))
  test_set = SimpleNamespace(images=gt[None], ids=[0], depths=depth)
  eval_dir = tmp_path / 'reference' / 'test_preds_step_5'
  eval_dir.mkdir(parents=True)
  np.savez(depth_metrics.depth_file(str(eval_dir), 0), distance=depth[0], acc=np.ones((8, 8)))
  keys |= set(depth_metrics.scorer(test_set, False)(0, depth[0] + .01))
  keys |= set(depth_metrics.reference_scorer(test_set, False, str(tmp_path / 'reference'), [0])(0, depth[0]))
  monkeypatch.setattr(depth_metrics.sfm_depth, 'evaluation_depths', lambda test_set, config: depth)
  keys |= set(depth_metrics.sfm_scorer(test_set, False, None)(0, depth[0]))
  summary = {'rotation_deg_median': 1., 'translation_median': .01}
  keys |= set(camera_evaluation.metrics({'final_vs_reference': summary, 'final_vs_reference_unaligned': summary},
                                        summary))
  return keys


def test_every_metric_the_evaluation_writes_is_registered(tmp_path, monkeypatch):
  written = _written_metrics(tmp_path, monkeypatch)
  assert written == set(IMAGE + MASKED + DEPTH + PSEUDO + SFM + CAMERAS)
  assert written == set(metric_registry.METRICS)


def test_derived_metric_lists_equal_the_former_literal_lists():
  assert metrics.FULL_METRICS == IMAGE and metrics.MASKED_METRICS == MASKED
  assert depth_metrics.DEPTH_METRICS == DEPTH and metric_registry.names(metric_registry.PSEUDO_DEPTH) == PSEUDO
  assert metric_registry.names(metric_registry.SFM_DEPTH) == SFM
  assert metric_registry.names(metric_registry.CAMERAS) == CAMERAS
  assert set(study_spec.LOWER_IS_BETTER) == {'lpips', 'avg_error', 'depth_mae', 'pseudo_depth_mae', 'sfm_depth_mae',
                                             'lpips_masked', 'avg_error_masked', *CAMERAS}
  assert tables.METRIC_GROUPS == {'dtu': (('object', MASKED), ('full', IMAGE)), 'llff': (('', IMAGE),),
                                  'blender': (('', IMAGE),), 'capture': (('', IMAGE),)}
  former_display = {'psnr': 'PSNR', 'ssim': 'SSIM', 'lpips': 'LPIPS', 'avg_error': 'Avg'}
  assert {m: tables.DISPLAY[m] for m in IMAGE} == former_display
  assert {m: tables.DISPLAY[m + '_masked'] for m in IMAGE} == former_display


def test_hand_picked_metric_lists_name_registered_metrics():
  assert set(study_export.TABLE_METRICS) <= set(metric_registry.METRICS)
  for path in sorted(ROOT.glob('studies/*.toml')):
    study = study_spec.load(path)
    plotted = [metric.split('@') for metric in study.plot.metrics]  # <metric> or <metric>@<evaluation>
    assert {p[0] for p in plotted} <= set(metric_registry.METRICS), path.name
    assert {p[1] for p in plotted if len(p) > 1} <= set(dict(study.evaluations)), path.name


def test_unknown_metric_group_and_unregistered_metric_are_refused():
  with pytest.raises(ValueError, match="metric group 'nope'"):
    metric_registry.names('nope')
  with pytest.raises(ValueError, match=r"metrics \['psnr2'\] are not in internal/evaluation/metric_registry.py"):
    results.make_record('llff', 'fern', 3, 'freenerf', 7, [{'id': 0, 'psnr': 20., 'psnr2': 1.}], True)


def test_derived_dataset_lists_equal_the_former_literal_lists():
  assert loader.LOADERS == ('dtu', 'llff', 'blender', 'generated', 'capture', 'packed')
  assert results.DATASETS == ('dtu', 'llff', 'blender', 'capture')
  assert results.EXPECTED_SCENES == {
      'dtu': ('scan8', 'scan21', 'scan30', 'scan31', 'scan34', 'scan38', 'scan40', 'scan41', 'scan45', 'scan55',
              'scan63', 'scan82', 'scan103', 'scan110', 'scan114'),
      'llff': ('fern', 'flower', 'fortress', 'horns', 'leaves', 'orchids', 'room', 'trex'),
      'blender': ('chair', 'drums', 'ficus', 'hotdog', 'lego', 'materials', 'mic', 'ship'), 'capture': ()}


# (loader, rig) -> (NDC rays, near must be > 0, (dataset, scene) of its runs), as config_loader and evaluate
# decided them by hand before the registry.
FORMER_RULES = {
    ('dtu', 'object'): (False, True, ('dtu', 'scan24')),
    ('llff', 'object'): (True, False, ('llff', 'horns')),
    ('blender', 'object'): (False, True, ('blender', 'ship')),
    ('generated', 'object'): (False, True, ('blender', 'generated_object')),
    ('generated', 'forward'): (True, False, ('llff', 'generated_forward')),
}


@pytest.mark.parametrize('name, rig', sorted(FORMER_RULES))
def test_ray_space_and_filing_follow_the_former_rules(name, rig):
  config = Config(dataset_loader=name, generated_rig=rig, dtu_scan='scan24', llff_scan='horns', blender_scene='ship')
  ndc, positive_near, filed = FORMER_RULES[name, rig]
  assert loader.ndc(config) is ndc
  assert (loader.ndc(config) is False) == positive_near
  assert loader.filed_as(config) == filed
  assert filed[0] in results.DATASETS


def test_packed_scenes_leave_near_far_to_the_pack():
  assert loader.ndc(Config(dataset_loader='packed', data_dir='absent.npz')) is None


def test_every_record_is_consistent():
  for name, record in loader.REGISTRY.items():
    for _, group in record.table_groups:
      assert metric_registry.names(group)
    if record.filed_as is None:  # A dataset of its own: named by a Config field (or a function of Config).
      assert callable(record.scene_setting) or record.scene_setting in {f.name for f in dataclasses.fields(Config)}
      assert record.protocol_scenes or name == 'capture', name  # Captures are users' scenes: no protocol.
    for setting, options in record.choices:
      assert setting in {f.name for f in dataclasses.fields(Config)} and options, name


def test_unknown_loader_and_unpackable_loader_name_the_setting():
  with pytest.raises(DatasetError, match=r"Config.dataset_loader = 'nope'; expected one of \['dtu'"):
    loader.load_dataset('train', Config(dataset_loader='nope'))
  packable = r"\['dtu', 'llff', 'blender', 'generated'\]"
  with pytest.raises(DatasetError, match=r"'packed' scenes cannot be packed; .*one of " + packable):
    loader.pack_arrays(Config(dataset_loader='packed'), {})


def test_random_poses_come_from_the_loaders_that_have_them():
  having = [name for name, record in loader.REGISTRY.items() if record.random_pose_cameras]
  assert having == ['dtu', 'llff', 'generated', 'capture']
  for name in ('blender', 'packed'):
    with pytest.raises(ValueError, match=r"^Config.depth_tvnorm_loss_mult / depth_tvnorm_decay: random poses exist "
                                         r"for scenes of Config.dataset_loader in \['dtu', 'llff', 'generated', "
                                         r"'capture'\] "
                                         rf"only; this Config.dataset_loader = '{name}' scene has none$"):
      loader.random_pose_cameras(None, Config(dataset_loader=name), np.random.default_rng(0))


def test_records_take_the_loader_files_functions_and_settings():
  """Loader.of fills a record from its file; the values equal the former hand-written records'."""
  for name, record in loader.REGISTRY.items():
    module = getattr(loader, name)
    assert (record.load, record.render_path) == (module.load_scene, module.scene_render_path), name
  assert [name for name, record in loader.REGISTRY.items() if record.pack_cameras] == [
      'dtu', 'llff', 'blender', 'generated']
  # The settings each loader's data depends on (declared in internal/configs.py), besides those of every loader.
  assert {name: configs.shaping_settings(name) for name in loader.REGISTRY} == {
      'dtu': ('dtu_scan', 'dtu_light_cond', 'dtu_max_images', 'dtu_split_type', 'dtuhold', 'near', 'far',
              'near_origin'),
      'llff': ('llff_scan', 'llffhold'),
      'blender': ('blender_scene', 'blender_split', 'white_background', 'near', 'far', 'pixel_offset'),
      'generated': ('llffhold', 'white_background', 'near', 'far', 'pixel_offset', 'generated_rig', 'generated_size',
                    'generated_seed'),
      'capture': ('llffhold', 'capture_scene', 'capture_images', 'capture_model', 'capture_rig', 'capture_train_model'),
      'packed': ()}
  assert [name for name, record in loader.REGISTRY.items() if record.mesh_bounds] == [
      'dtu', 'blender', 'generated', 'capture']
  assert loader.SETTING_CHOICES == (
      ('dataset_loader', loader.LOADERS), ('dtu_layout', ('auto', 'regnerf', 'idr')),
      ('blender_split', ('dietnerf', 'first_n')), ('generated_rig', ('object', 'forward')),
      ('capture_rig', ('auto', 'inward', 'forward')))
  assert [loader.REGISTRY[name].ndc(Config()) for name in ('dtu', 'llff', 'blender')] == [False, True, False]
