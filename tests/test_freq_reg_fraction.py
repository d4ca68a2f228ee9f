"""T as a fraction of the steps (Config.freq_reg_end_fraction), resolved into Config.freq_reg_end when the config
loads; the mini configs, the demo and the study files give T so, and every run they make keeps the T it had when they
gave it in steps (the tables below are those step counts, resolved from the files before the change)."""

import pytest

from internal import runs
from lab.study import spec as study_spec

DEMO = ['configs/demo.gin']
FORWARD = DEMO + ['configs/demo_forward.gin']
# (gin files) -> (max_steps, T) as they resolved when the files gave T in steps.
CONFIGS = {
    ('configs/demo.gin',): (700, 350), tuple(FORWARD): (500, 450),
    tuple(FORWARD + ['configs/demo_nerf.gin']): (500, 0),
    ('configs/mini/blender.gin',): (2000, 1000), ('configs/mini/dtu3_freenerf.gin',): (2000, 1800),
    ('configs/mini/llff3_freenerf.gin',): (2000, 1800), ('configs/mini/capture3_freenerf.gin',): (2000, 1800),
    ('configs/mini/capture6_freenerf.gin',): (2000, 1400), ('configs/mini/capture9_freenerf.gin',): (2000, 1000),
    ('configs/mini/dtu3_freenerf.gin', 'configs/mini/quick.gin'): (1000, 900),
}
QUICK, MINI, LONG = (1000, 900), (2000, 1800), (8000, 7200)
# Per study file: {cell id without its seed: (max_steps, T)}; a cell missing here resolves to T = 0 (mip-NeRF's).
STUDIES = {
    't_sweep': {f'freenerf__dtu_scan24__T={t}': (1000, round(t * 1000)) for t in (0.1, 0.3, 0.5, 0.9, 1.0)},
    't_sweep_mini': {f'freenerf__dtu_scan24__T={t}': (2000, round(t * 2000))
                     for t in (0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 1.0)},
    'example_generated': {'freenerf__object__T=0.1': (200, 20), 'freenerf__object__T=0.5': (200, 100),
                          'freenerf__object__T=0.9': (200, 180)},
    'speed_accuracy': {f'freenerf__dtu_scan24__variant={v}': (1000, 900) if v == 'steps1000' else MINI
                       for v in ('base', 'batch512', 'depth8', 'samples16', 'samples64', 'steps1000', 'width256',
                                 'width64')},
    'speed_accuracy_generated': {f'freenerf__object__variant={v}': (1400, 700) if v == 'steps1400' else (700, 350)
                                 for v in ('base', 'depth2', 'depth8', 'samples16', 'samples64', 'steps1400',
                                           'width128')},
    'mini_dtu_seeds': {'freenerf__dtu_scan24': MINI, 'freenerf_T0__dtu_scan24': (2000, 0)},
    'seeds_dtu_quick': {'freenerf__dtu_scan24': QUICK, 'freenerf_T0__dtu_scan24': (1000, 0)},
    'seeds_llff_quick': {'freenerf__fern': QUICK},
    'depth': {'freenerf__dtu_scan24': QUICK},
    'occlusion': {f'freenerf__dtu_scan24__variant={v}': QUICK
                  for v in ('M5', 'M10', 'M15', 'M20', 'M25', 'no_Locc', 'distortion', 'bw_prior_only', 'no_bw_prior')},
    'near_bound': {f'{m}__dtu_scan24__near={n}': QUICK for m in ('freenerf', 'freenerf_no_Locc')
                   for n in ('0.5', '1.0', '1.5', '2.0')},
    'mini_dtu_long': {'freenerf__dtu_scan24': LONG},
    'mini_llff_long': {'freenerf__fern': LONG},
    'capture_cup': {'freenerf__cup': MINI, 'freenerf_nerf__cup': MINI},
    'depth_prior_cup': {'freenerf__cup': (700, 630), 'freenerf_sfm__cup': (700, 630)},
    'cameras_cup': {f'freenerf__cup__cameras={c}': (800, 560) for c in ('allphoto', 'sfm6', 'sfm6_refine',
                                                                                   'sfm6_prior', 'sfm6_refine_prior')},
    'depth_prior_cup_9views': {f'{m}__cup': (700, 350) for m in ('freenerf', 'freenerf_sfm', 'freenerf_sfm_strict')},
}
# Study files that once bound T in steps by hand (issue 59): T is now their method's gin fraction of the steps.
FRACTION_STUDIES = ('depth_prior_cup', 'cameras_cup', 'depth_prior_cup_9views')


def resolved(configs, bindings=()) -> tuple:
  """(max_steps, freq_reg_end) of the config the files and bindings load to."""
  config = runs.bind_fresh(list(configs), list(bindings))
  return config.max_steps, config.freq_reg_end


def test_a_fraction_gives_t_in_steps_when_the_config_loads():
  assert resolved(DEMO) == (700, 350)
  assert resolved(DEMO, ['Config.max_steps = 901']) == (901, 450)           # round(450.5): to even.
  assert resolved(DEMO, ['Config.freq_reg_end_fraction = 0.25']) == (700, 175)
  assert resolved(DEMO, ['Config.freq_reg_end_fraction = None']) == (700, 0)  # Steps again: the default T.


def test_a_step_count_in_the_bindings_wins_over_a_fraction_from_the_files():
  assert resolved(DEMO, ['Config.freq_reg_end = 123']) == (700, 123)
  assert runs.bind_fresh(DEMO, ['Config.freq_reg_end = 123']).freq_reg_end_fraction is None


def test_of_steps_and_fraction_the_later_binding_wins_across_files_includes_and_bindings(tmp_path):
  steps, fraction = tmp_path / 'steps.gin', tmp_path / 'fraction.gin'
  steps.write_text('Config.freq_reg_end = 3\n')
  fraction.write_text('Config.freq_reg_end_fraction = 0.25\n')
  assert resolved(DEMO + [str(steps)]) == (700, 3)  # A later file's steps over demo.gin's fraction.
  assert resolved(DEMO + [str(steps), str(fraction)]) == (700, 175)
  including = tmp_path / 'including.gin'  # An include binds where it stands in its file.
  including.write_text(f"include '{fraction}'\nConfig.freq_reg_end = 5\n")
  assert resolved(DEMO + [str(including)]) == (700, 5)
  including.write_text(f"Config.freq_reg_end = 5\ninclude '{fraction}'\n")
  assert resolved(DEMO + [str(including)]) == (700, 175)
  assert resolved(DEMO, ['Config.freq_reg_end = 9', 'Config.freq_reg_end_fraction = 0.5']) == (700, 350)
  assert resolved(DEMO, ['Config.freq_reg_end_fraction = 0.5', 'Config.freq_reg_end = 9']) == (700, 9)
  assert resolved(DEMO, ['Config.freq_reg_end_fraction = 0.5\nConfig.freq_reg_end = 9']) == (700, 9)
  assert resolved(DEMO + [str(steps)], ['Config.freq_reg_end_fraction = 0.1']) == (700, 70)


def test_the_released_files_keep_t_in_steps():
  assert resolved(['configs/freenerf/dtu3_freenerf.gin']) == (43945, 39550)
  assert resolved(['configs/freenerf/dtu3_freenerf.gin'], ['Config.freq_reg_end_fraction = 0.5']) == (43945, 21972)


@pytest.mark.parametrize('bindings,message', [
    (['Config.freq_reg_end_fraction = -0.1'], r'freq_reg_end_fraction = -0.1; expected a finite number >= 0'),
    (["Config.freq_reg_end_fraction = 'half'"], "freq_reg_end_fraction = 'half'; expected a finite number"),
    (['Config.freq_reg_end_fraction = True'], 'freq_reg_end_fraction = True; expected a finite number'),
])
def test_a_bad_fraction_is_one_error_naming_it(bindings, message):
  with pytest.raises(ValueError, match=message):
    resolved(DEMO, bindings)


@pytest.mark.parametrize('configs', CONFIGS, ids=' '.join)
def test_each_config_keeps_the_t_it_had_in_steps(configs):
  assert resolved(configs) == CONFIGS[configs]


@pytest.mark.parametrize('name', STUDIES)
def test_each_study_cell_keeps_the_t_it_had_in_steps(name):
  study = study_spec.load(f'studies/{name}.toml')
  found = {}
  for cell in study_spec.cells(study):
    key = '__'.join(p for p in cell.cell_id.split('__') if not p.startswith(f'{study_spec.SEED_AXIS}='))
    if key not in found:  # The seeds of a setting bind nothing else.
      found[key] = resolved(*study_spec.cell_gin(study, cell, 'out', '../shared/data', 'out/cell'))
  assert {k: v for k, v in found.items() if v[1] or k in STUDIES[name]} == STUDIES[name]


@pytest.mark.parametrize('name', FRACTION_STUDIES)
def test_these_studies_take_t_from_the_fraction_of_their_gin(name):
  study = study_spec.load(f'studies/{name}.toml')
  for cell in study_spec.cells(study):
    config = runs.bind_fresh(*study_spec.cell_gin(study, cell, 'out', '../shared/data', 'out/cell'))
    assert config.freq_reg_end_fraction is not None, f'{name}: {cell.cell_id} binds T in steps'
    assert config.freq_reg_end == round(config.freq_reg_end_fraction * config.max_steps)
