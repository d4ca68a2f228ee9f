"""Train-step and rendering benchmark on this machine, paper model; all ratios measured in one run.

Usage: python -m bench.train_step [--batch 256] [--repeats 5] [--render_rays 8192]

Reports, side by side:
  1. FreeNeRF step (both regularizers on) / plain mip-NeRF step (both off);
  2. our FreeNeRF step / a released-equivalent graph (per-sample vmap(value_and_grad), tiled masks);
  3. achieved GFLOP/s of our step (XLA's flop count / time) against a matmul peak measured here;
  4. test-image rendering rays/s, ours vs the released-equivalent that materializes normals.
"""

import argparse
import json
import statistics
import time

import gin
import jax
import jax.numpy as jnp
import numpy as np
from jax import random

from bench import released_equivalent
from internal import configs
from internal import inference
from internal.models import MipNerfModel
from internal import rays as rays_lib
from internal import train_step as ts

PAPER_DTU3 = dict(near=0.5, far=3.5, white_background=False, max_steps=43945, lr_init=2e-3,
                  lr_final=2e-5, lr_delay_steps=512, lr_delay_mult=0.01, grad_max_norm=0.1,
                  grad_max_val=0.1)
FREENERF = dict(freq_reg=True, freq_reg_end=39550, occ_reg_loss_mult=0.01, occ_wb_prior=True)


def dtu_like_rays(num_rays: int, seed: int = 0) -> rays_lib.Rays:
  """Rays [num_rays, ...] from a camera 2 units from the origin, DTU near/far."""
  rng = np.random.default_rng(seed)
  directions = np.concatenate([rng.uniform(-0.3, 0.3, (num_rays, 2)), np.ones((num_rays, 1))], -1)
  ones = np.ones((num_rays, 1))
  rays = rays_lib.Rays(np.zeros((num_rays, 3)) + [0., 0., -1.], directions,
                       directions / np.linalg.norm(directions, axis=-1, keepdims=True),
                       ones * 1e-3, ones, ones * 0.5, ones * 3.5)
  return rays_lib.map_rays(lambda x: jnp.asarray(x, jnp.float32), rays)


def block(tree):
  """Waits for every array of tree."""
  return jax.block_until_ready(tree)


def matmul_peak(repeats: int) -> float:
  """Best GFLOP/s of a jit f32 [32768, 256] @ [256, 256] matmul (the MLP's shape)."""
  a = random.normal(random.PRNGKey(0), (32768, 256))
  b = random.normal(random.PRNGKey(1), (256, 256))
  f = jax.jit(lambda a, b: a @ b)
  block(f(a, b))
  best = min(_timed(lambda: block(f(a, b))) for _ in range(repeats * 4))
  return 2 * 32768 * 256 * 256 / best / 1e9


def _timed(fn) -> float:
  start = time.perf_counter()
  fn()
  return time.perf_counter() - start


def build_step(model_cls, overrides, batch):
  """(jitted step, state, flops per step) for the paper model under Config overrides."""
  config = configs.Config(**PAPER_DTU3, **overrides)
  _, state = ts.create_train_state(config, random.PRNGKey(0), batch['rays'])
  step = ts.make_train_step(config, model_cls(white_background=False))
  key = random.PRNGKey(1)
  flops = step.lower(state, batch, key).compile().cost_analysis()
  flops = (flops[0] if isinstance(flops, list) else flops).get('flops', float('nan'))
  state, _ = block(step(state, batch, key))
  return step, state, flops


def time_steps(variants, batch, repeats: int):
  """Median seconds per step of each variant, timed interleaved (A, B, C, A, B, C, ...)."""
  key = random.PRNGKey(1)
  times = {name: [] for name in variants}
  for _ in range(repeats):
    for name, (step, state, _) in variants.items():
      start = time.perf_counter()
      state, _ = block(step(state, batch, key))
      times[name].append(time.perf_counter() - start)
      variants[name] = (step, state, variants[name][2])
  return {name: statistics.median(t) for name, t in times.items()}


def released_render_fn(model, params, config, step):
  """jit-compiled rays [N, ...] -> fine outputs plus the per-sample normals the released code keeps."""
  mask_point, mask_view = ts.masks_at(config, jnp.asarray(step))

  @jax.jit
  def render(chunk_rays):
    (renderings, _), state = model.apply({'params': params}, None, chunk_rays, mask_point, mask_view,
                                         config.resample_padding_final, compute_extras=True,
                                         mutable=['intermediates'])
    normals = state['intermediates']['mlp']['normals'][-1]
    out = {k: renderings[-1][k] for k in inference.OUTPUT_KEYS}
    return dict(out, normals=normals.reshape(chunk_rays.origins.shape[0], -1))
  return render


def render_rate(render_fn, num_rays: int, chunk: int, repeats: int) -> float:
  """Best rays/s of rendering num_rays rays in chunks (compile excluded)."""
  rays = dtu_like_rays(num_rays, seed=2)
  block(render_fn(rays_lib.map_rays(lambda x: x[:chunk], rays)))
  return num_rays / min(_timed(lambda: inference.render_image(render_fn, rays, chunk))
                        for _ in range(repeats))


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument('--batch', type=int, default=256)
  parser.add_argument('--repeats', type=int, default=5)
  parser.add_argument('--render_rays', type=int, default=8192)
  parser.add_argument('--chunk', type=int, default=4096)
  args = parser.parse_args()
  gin.parse_config(['MLP.density_noise = 1.0'])
  batch = {'rays': dtu_like_rays(args.batch),
           'rgb': jnp.asarray(np.random.default_rng(1).uniform(size=(args.batch, 3)), jnp.float32)}
  peak = matmul_peak(args.repeats)
  variants = {
      'freenerf': build_step(MipNerfModel, FREENERF, batch),
      'mipnerf': build_step(MipNerfModel, {}, batch),
      'released_freenerf': build_step(released_equivalent.ReleasedModel, FREENERF, batch),
  }
  flops = variants['freenerf'][2]
  times = time_steps(variants, batch, args.repeats)
  config = configs.Config(**PAPER_DTU3, **FREENERF)
  params = variants['freenerf'][1].params
  ours = render_rate(inference.make_render_fn(config, MipNerfModel(white_background=False), params,
                                             config.max_steps), args.render_rays, args.chunk, 2)
  released = render_rate(released_render_fn(released_equivalent.ReleasedModel(white_background=False),
                                            params, config, config.max_steps),
                         args.render_rays, args.chunk, 2)
  achieved = flops / times['freenerf'] / 1e9
  report = {
      'devices': str(jax.devices()), 'batch': args.batch, 'step_seconds': times,
      'freenerf_over_mipnerf': times['freenerf'] / times['mipnerf'],
      'ours_over_released_equivalent': times['freenerf'] / times['released_freenerf'],
      'step_gflop': flops / 1e9, 'achieved_gflops': achieved, 'matmul_peak_gflops': peak,
      'fraction_of_peak': achieved / peak,
      'render_rays_per_s': {'ours': ours, 'released_equivalent_with_normals': released},
      'render_speedup': ours / released,
  }
  print(json.dumps(report, indent=2))


if __name__ == '__main__':
  main()
