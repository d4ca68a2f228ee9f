"""The CPU mini-protocol configs (configs/mini/): their scaled schedule, and a few steps on the shared scenes."""

import os

import pytest

from conftest import SHARED_DATA
from internal import config_loader
from internal import runs
from internal.evaluation import evaluate
from internal.models import mip_nerf
from internal.models import nerf
from internal.pipeline import loop

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = {'dtu': ["Config.data_dir = '{root}/dtu'", "Config.dtu_scan = 'dtu_scan24'", "Config.dtu_mask_path = ''",
                'Config.allow_missing_test_views = True'],
        'llff': ["Config.data_dir = '{root}/llff'", "Config.llff_scan = 'fern'"]}
PAPER_STEPS = {'dtu': 43945, 'llff': 69768}  # The 3-view configs' step counts, over which the schedule is scaled.


def _config(dataset: str, method: str, *bindings):
  path = os.path.join(REPO, 'configs', 'mini', f'{dataset}3_{method}.gin')
  return config_loader.load_config([path], [b.format(root=SHARED_DATA) for b in DATA[dataset]] + list(bindings))


@pytest.mark.parametrize('dataset', ['dtu', 'llff'])
@pytest.mark.parametrize('method', ['freenerf', 'mipnerf', 'regnerf'])
def test_mini_config_is_the_paper_config_at_the_mini_scale(dataset, method):
  config = _config(dataset, method)
  mlp, model = mip_nerf.MLP(), mip_nerf.MipNerfModel()
  assert (mlp.net_depth, mlp.net_width, model.num_samples, config.batch_size) == (4, 128, 32, 512)
  assert config.max_steps == 2000 and config.n_input_views == 3 and config.expname == method
  assert config.lr_delay_steps == round(512 * 2000 / PAPER_STEPS[dataset])    # Warm-up scaled as the steps.
  assert (config.lr_init, config.lr_final, config.grad_max_norm) == (2e-3, 2e-5, .1)
  assert config.freq_reg == (method == 'freenerf')
  assert config.freq_reg_end == (1800 if method == 'freenerf' else 0)          # T = 0.9 x steps.
  assert config.factor == {'dtu': 8, 'llff': 16}[dataset]
  if method == 'regnerf':
    assert config.anneal_nearfar and config.depth_tvnorm_maxstep == round(512 * 2000 / PAPER_STEPS['dtu'])


@pytest.mark.skipif(not SHARED_DATA.is_dir(), reason=f'real scenes absent: {SHARED_DATA} does not exist')
@pytest.mark.parametrize('dataset,method', [('dtu', 'freenerf'), ('llff', 'regnerf')])
def test_mini_config_trains_and_evaluates_on_the_shared_scene(tmp_path, dataset, method):
  config = _config(dataset, method, f"Config.checkpoint_dir = '{tmp_path / 'run'}'", 'Config.max_steps = 3',
                   'Config.batch_size = 64', 'Config.batch_size_random = 64', 'Config.compute_lpips = False',
                   'Config.eval_test_ids = [0]')
  assert int(loop.train(config).state.step) == 3
  record = evaluate.evaluate(config)
  assert record['step'] == 3 and len(record['per_image']) == 1 and record['means']['psnr'] > 0.


@pytest.mark.parametrize('method', ['nerf', 'freenerf'])
def test_mini_blender_config_is_the_paper_config_at_the_cpu_scale(method):
  paper = os.path.join(REPO, 'configs', method, f'blender8_{method}.gin')
  config = config_loader.load_config([paper, os.path.join(REPO, 'configs', 'mini', 'blender.gin')])
  mlp, model = nerf.NerfMLP(), nerf.NerfModel()
  assert config.model == 'nerf' and config.n_input_views == 8 and config.factor == 8
  assert (mlp.net_depth, mlp.net_width, model.num_coarse_samples, model.num_fine_samples) == (4, 64, 32, 32)
  assert config.lr_final == pytest.approx(5e-4 * 0.1**(config.max_steps / 500_000), rel=1e-6)  # 0.1^(t/500k).
  assert config.precrop_steps == round(500 * config.max_steps / 50_000)                         # 1% of the steps.
  assert config.freq_reg == (method == 'freenerf')
  # Alone after either paper config: T = 0.5 x steps and occlusion on 7 of the 64 fine samples (20 of 192).
  assert config.freq_reg_end == config.max_steps // 2 and config.occ_reg_range == round(20 * 64 / 192)
  assert mlp.weight_init == 'xavier' and config.pixel_offset == 0.  # The released Blender code's, kept.


# DTU's (steps, T) per view count, the capture configs' schedules, written out here independently of the files.
CAPTURE_PAPER = {3: (43945, 39550), 6: (87891, 61524), 9: (131836, 65918)}


@pytest.mark.parametrize('views', [3, 6, 9])
@pytest.mark.parametrize('method', ['freenerf', 'mipnerf'])
def test_capture_mini_configs_scale_dtus_schedule_for_their_view_count(views, method):
  paper = config_loader.load_config([os.path.join(REPO, 'configs', method, f'capture{views}_{method}.gin')])
  steps, end = CAPTURE_PAPER[views]
  assert (paper.max_steps, paper.freq_reg_end) == (steps, end if method == 'freenerf' else 0)
  config = runs.bind_fresh([os.path.join(REPO, 'configs', 'mini', f'capture{views}_{method}.gin')])
  assert config.max_steps == 2000 and config.n_input_views == views and config.dataset_loader == 'capture'
  assert config.lr_delay_steps == round(512 * 2000 / steps)                          # Warm-up scaled as the steps.
  assert config.freq_reg_end == (round(2000 * end / steps, -2) if method == 'freenerf' else 0)  # T: 0.9, 0.7, 0.5.
  assert config.factor == 4 and config.curve_every == 250
