"""Our train step and rendering against mip-NeRF's and the released code's graph, paper model; ratios in one run.

Usage: python -m bench.released_comparison [--batch 256] [--repeats 5] [--render_rays 8192] [--render_repeats 3]
       python -m bench.released_comparison --nerf_only [--batch 256] [--repeats 5]

Reports, side by side:
  1. FreeNeRF step (both regularizers on) / plain mip-NeRF step (both off), and RegNeRF step (depth TV on
     batch_size_random = batch random-pose rays in 8x8 patches, near/far annealing) / mip-NeRF step, beside the
     ratio of their XLA flop counts (how much of RegNeRF's extra time is extra work);
     FreeNeRF-on-NeRF step / plain NeRF step (the paper's Blender setting: 64 + 128 samples, paper mask layout,
     occlusion on the first 20 of 192 fine samples; the paper reports 1.02x); --nerf_only times just that pair;
  2. our FreeNeRF step / a released-equivalent graph (per-sample vmap(value_and_grad), tiled masks);
  3. achieved GFLOP/s of our step (XLA's flop count / time) against a matmul peak measured here
     (best of 8 runs of MATMUL_SHAPES; the mean of the 8 is reported as the sustained rate);
  4. test-image rendering rays/s, ours vs the released-equivalent that materializes normals.
"""

import argparse
import functools
import json
import statistics
import sys

import gin
import jax
import jax.numpy as jnp
import numpy as np

from bench import common
from bench import released_equivalent
from internal import cli
from internal.models import freq_schedule
from internal import configs
from internal.evaluation import inference
from internal.models.mip_nerf import MipNerfModel
from internal.models.nerf import NerfModel
from internal import rays as rays_lib

PAPER_DTU3 = dict(near=0.5, far=3.5, white_background=False, max_steps=43945, lr_init=2e-3,
                  lr_final=2e-5, lr_delay_steps=512, lr_delay_mult=0.01, grad_max_norm=0.1,
                  grad_max_val=0.1)
FREENERF = dict(freq_reg=True, freq_reg_end=39550, occ_reg_loss_mult=0.01, occ_wb_prior=True)
FREENERF_ON_NERF = dict(model='nerf', freq_reg=True, freq_reg_end=25000, freq_mask_layout='released',
                        occ_reg_loss_mult=0.03, occ_reg_range=20)
REGNERF = dict(anneal_nearfar=True, anneal_nearfar_steps=256, anneal_nearfar_perc=0.5, depth_tvnorm_loss_mult=0.1,
               depth_tvnorm_decay=True, depth_tvnorm_maxstep=512, depth_tvnorm_loss_mult_start=400.,
               depth_tvnorm_loss_mult_end=0.1, depth_tvnorm_mask_weight=1.0, patch_size=8)


# [rows, C] @ [C, C] matmuls of the MLP's width: a cache-sized one (the fastest shape on a 2-core CPU) and
# one as tall as a batch-256 level; the peak is the faster of the two.
MATMUL_SHAPES = ((4096, 256, 256), (32768, 256, 256))


def matmul_runner(reduce):
  """Zero-arg callable: seconds per flop, reduce (min: peak, mean: sustained) over 8 runs of each shape."""
  return common.matmul_runner(MATMUL_SHAPES, reduce)


def step_runner(model_cls, overrides, batch):
  """(zero-arg callable returning one step's seconds, params, flops per step) for the paper model."""
  config = configs.Config(**PAPER_DTU3, **overrides)
  run, holder, xla = common.step_runner(config, model_cls(white_background=False), batch)
  return run, holder, xla['flops']


interleaved_medians = common.interleaved_medians


def nerf_step_runners(batch):
  """{'freenerf_nerf', 'nerf'}: step_runner results of FreeNeRF on plain NeRF and of plain NeRF (paper-size)."""
  return {'freenerf_nerf': step_runner(NerfModel, FREENERF_ON_NERF, batch),
          'nerf': step_runner(NerfModel, dict(model='nerf'), batch)}


def nerf_report(args, batch):
  """Step seconds of the NeRF pair and their ratio (the --nerf_only report)."""
  runners = {name: run for name, (run, _, _) in nerf_step_runners(batch).items()}
  times = interleaved_medians(runners, args.repeats)
  return {'devices': str(jax.devices()), 'batch': args.batch, 'step_seconds': times,
          'freenerf_nerf_over_nerf': times['freenerf_nerf'] / times['nerf']}


def released_render_fn(model, params, config, step):
  """jit-compiled rays [N, ...] -> fine outputs plus the per-sample normals the released code keeps."""
  mask_point, mask_view = freq_schedule.masks_at(config, model.mlp.encoding_degrees(), jnp.asarray(step))

  @jax.jit
  def render(params, chunk_rays):
    (renderings, _), state = model.apply({'params': params}, None, chunk_rays, mask_point, mask_view,
                                         config.resample_padding_final, compute_extras=True,
                                         mutable=['intermediates'])
    normals = state['intermediates']['mlp']['normals'][-1]
    out = {k: renderings[-1][k] for k in inference.OUTPUT_KEYS}
    return dict(out, normals=normals.reshape(chunk_rays.origins.shape[0], -1))
  return functools.partial(render, params)  # Parameters as an argument, as in make_render_fn.


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--batch', type=int, default=256)
  parser.add_argument('--repeats', type=int, default=5)
  parser.add_argument('--render_rays', type=int, default=8192)
  parser.add_argument('--chunk', type=int, default=4096)
  parser.add_argument('--render_repeats', type=int, default=3)
  parser.add_argument('--nerf_only', action='store_true', help='time only FreeNeRF-on-NeRF against NeRF')
  args = parser.parse_args()
  gin.parse_config(['MLP.density_noise = 1.0'])
  batch = {'rays': common.dtu_like_rays(args.batch),
           'rgb': jnp.asarray(np.random.default_rng(1).uniform(size=(args.batch, 3)), jnp.float32)}
  if args.nerf_only:
    print(json.dumps(nerf_report(args, batch), indent=2))
    return
  steps = {name: step_runner(model_cls, overrides, batch) for name, model_cls, overrides in (
      ('freenerf', MipNerfModel, FREENERF), ('mipnerf', MipNerfModel, {}),
      ('released_freenerf', released_equivalent.ReleasedModel, FREENERF))}
  steps.update(nerf_step_runners(batch))
  patches = rays_lib.map_rays(lambda x: x.reshape((-1, 8, 8, x.shape[-1])), common.dtu_like_rays(args.batch, seed=3))
  steps['regnerf'] = step_runner(MipNerfModel, dict(REGNERF, batch_size_random=args.batch),
                                 dict(batch, patch_rays=patches))
  runners = {name: run for name, (run, _, _) in steps.items()}
  runners.update(matmul_peak=matmul_runner(min), matmul_sustained=matmul_runner(statistics.mean))
  times = interleaved_medians(runners, args.repeats)
  flops = steps['freenerf'][2]
  peak, sustained = (1 / times.pop(name) / 1e9 for name in ('matmul_peak', 'matmul_sustained'))
  config = configs.Config(**PAPER_DTU3, **FREENERF)
  params = steps['freenerf'][1][0].params
  renders = interleaved_medians({
      'ours': common.render_runner(inference.make_render_fn(
          config, MipNerfModel(white_background=False), params, config.max_steps),
          args.render_rays, args.chunk),
      'released_equivalent_with_normals': common.render_runner(released_render_fn(
          released_equivalent.ReleasedModel(white_background=False), params, config, config.max_steps),
          args.render_rays, args.chunk)}, args.render_repeats)
  rays_per_s = {name: args.render_rays / seconds for name, seconds in renders.items()}
  achieved = flops / times['freenerf'] / 1e9
  report = {
      'devices': str(jax.devices()), 'batch': args.batch, 'step_seconds': times,
      'freenerf_over_mipnerf': times['freenerf'] / times['mipnerf'],
      'regnerf_over_mipnerf': times['regnerf'] / times['mipnerf'],
      'regnerf_flops_over_mipnerf': steps['regnerf'][2] / steps['mipnerf'][2],  # Its extra work, beside its time.
      'freenerf_nerf_over_nerf': times['freenerf_nerf'] / times['nerf'],
      'ours_over_released_equivalent': times['freenerf'] / times['released_freenerf'],
      'step_gflop': flops / 1e9, 'achieved_gflops': achieved, 'matmul_peak_gflops': peak,
      'fraction_of_peak': achieved / peak, 'matmul_sustained_gflops': sustained,
      'fraction_of_sustained': achieved / sustained,
      'render_rays_per_s': rays_per_s,
      'render_speedup': rays_per_s['ours'] / rays_per_s['released_equivalent_with_normals'],
  }
  print(json.dumps(report, indent=2))


if __name__ == '__main__':
  sys.exit(cli.run(main))
