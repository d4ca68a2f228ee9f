"""Our train step and rendering against mip-NeRF's and the released code's graph, paper model; ratios in one run.

Usage: python -m bench.released_comparison [--batch 256] [--repeats 5] [--render_rays 8192] [--render_repeats 3]
       python -m bench.released_comparison --nerf_only [--batch 256] [--repeats 5]

Each step's settings are its gin file's (GIN_FILES), at --batch rays. Reports, side by side:
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
import os
import statistics
import sys

import jax
import jax.numpy as jnp

from bench import common
from bench import released_equivalent
from internal import cli
from internal.evaluation import inference
from internal.models import freq_schedule
from internal.models import registry
from internal.models.mip_nerf import MipNerfModel

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# Each step's settings: its released gin file (DTU 3 views for the mip-NeRF family, Blender 8 views for NeRF).
GIN_FILES = {'freenerf': 'configs/freenerf/dtu3_freenerf.gin', 'mipnerf': 'configs/mipnerf/dtu3_mipnerf.gin',
             'regnerf': 'configs/regnerf/dtu3_regnerf.gin', 'freenerf_nerf': 'configs/freenerf/blender8_freenerf.gin',
             'nerf': 'configs/nerf/blender8_nerf.gin'}
NOISE = ['MLP.density_noise = 1.0']  # One noise draw a step, as the released code (and nothing compiled away).


# [rows, C] @ [C, C] matmuls of the MLP's width: a cache-sized one (the fastest shape on a 2-core CPU) and
# one as tall as a batch-256 level; the peak is the faster of the two.
MATMUL_SHAPES = ((4096, 256, 256), (32768, 256, 256))


def matmul_runner(reduce):
  """Zero-arg callable: seconds per flop, reduce (min: peak, mean: sustained) over 8 runs of each shape."""
  return common.matmul_runner(MATMUL_SHAPES, reduce)


def method_config(name: str, batch_size: int):
  """The validated Config of a step's gin file (parsed now, replacing earlier bindings) at batch_size rays (and as
  many random-pose rays for RegNeRF)."""
  random_rays = {'batch_size_random': batch_size} if name == 'regnerf' else {}
  return common.gin_config([os.path.join(ROOT, GIN_FILES[name])], NOISE, batch_size=batch_size, **random_rays)


def step_runner(name: str, batch, model_cls=None):
  """(zero-arg callable returning one step's seconds, [state, stats], flops per step) of a step of GIN_FILES,
  compiled right after its gin file is parsed (the model reads its bindings when traced)."""
  config = method_config(name, batch.rgb.shape[0])
  model = (model_cls(white_background=config.white_background) if model_cls else
           registry.build(config.model, white_background=config.white_background))
  run, holder, xla = common.step_runner(config, model, batch)
  return run, holder, xla['flops']


interleaved_medians = common.interleaved_medians


def nerf_step_runners(batch):
  """{'freenerf_nerf', 'nerf'}: step_runner results of FreeNeRF on plain NeRF and of plain NeRF (paper-size)."""
  return {name: step_runner(name, batch) for name in ('freenerf_nerf', 'nerf')}


def nerf_report(args, batch):
  """Step seconds of the NeRF pair and their ratio (the --nerf_only report)."""
  runners = {name: run for name, (run, _, _) in nerf_step_runners(batch).items()}
  times = interleaved_medians(runners, args.repeats)
  return {'devices': str(jax.devices()), 'batch': args.batch, 'step_seconds': times,
          'freenerf_nerf_over_nerf': times['freenerf_nerf'] / times['nerf']}


def released_render_fn(model, params, config, step):
  """jit-compiled rays [N, ...] -> fine outputs plus the per-sample normals the released code keeps."""
  mask_point, mask_view = freq_schedule.model_masks(config, model, jnp.asarray(step))

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
  batch = common.dtu_like_batch(args.batch)
  if args.nerf_only:
    print(json.dumps(nerf_report(args, batch), indent=2))
    return
  steps = {name: step_runner(name, batch) for name in ('mipnerf', 'freenerf')}
  steps['released_freenerf'] = step_runner('freenerf', batch, released_equivalent.ReleasedModel)
  steps.update(nerf_step_runners(batch))
  steps['regnerf'] = step_runner('regnerf', common.with_patches(batch, method_config('regnerf', args.batch)))
  runners = {name: run for name, (run, _, _) in steps.items()}
  runners.update(matmul_peak=matmul_runner(min), matmul_sustained=matmul_runner(statistics.mean))
  times = interleaved_medians(runners, args.repeats)
  flops = steps['freenerf'][2]
  peak, sustained = (1 / times.pop(name) / 1e9 for name in ('matmul_peak', 'matmul_sustained'))
  config = method_config('freenerf', args.batch)  # The renders compile under FreeNeRF's bindings again.
  params = steps['freenerf'][1][0].params
  renders = interleaved_medians({
      'ours': common.render_runner(inference.make_render_fn(
          config, MipNerfModel(white_background=config.white_background), params, config.max_steps),
          args.render_rays, args.chunk),
      'released_equivalent_with_normals': common.render_runner(released_render_fn(
          released_equivalent.ReleasedModel(white_background=config.white_background), params, config,
          config.max_steps), args.render_rays, args.chunk)}, args.render_repeats)
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
