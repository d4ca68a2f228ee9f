"""Pieces shared by the benchmarks: waiting and timing, interleaved medians, matmul rates, a compiled step."""

import dataclasses
import functools
import statistics
import time

import gin
import jax
import jax.numpy as jnp
from jax import random
import numpy as np

from internal import config_loader
from internal import configs
from internal import rays as rays_lib
from internal.datasets import batching, random_poses
from internal.evaluation import inference
from internal.training import flops
from internal.training import train_step as ts


def gin_config(files, bindings, **overrides) -> configs.Config:
  """The validated Config of gin files and bindings (parsed now, replacing any earlier bindings), with overrides."""
  gin.clear_config()
  config_loader.parse_gin(files, bindings)
  config = dataclasses.replace(configs.Config(), **overrides)
  config_loader.validate(config)
  return config


def names_of(text: str, options, flag: str):
  """The comma-separated names of a flag's value, each one of options (ValueError naming the flag otherwise)."""
  names = [n for n in text.split(',') if n]
  unknown = [n for n in names if n not in options]
  if unknown or not names:
    raise ValueError(f'{flag} {text!r}: expected comma-separated names among {list(options)}')
  return names


def block(tree):
  """Waits for every array of tree."""
  return jax.block_until_ready(tree)


def timed(fn) -> float:
  """Seconds fn() takes."""
  start = time.perf_counter()
  fn()
  return time.perf_counter() - start


def interleaved_medians(runners, repeats: int):
  """Median result of each zero-arg runner, run interleaved (A, B, C, A, B, C, ...) to share the noise."""
  times = {name: [] for name in runners}
  for _ in range(repeats):
    for name, run in runners.items():
      times[name].append(run())
  return {name: statistics.median(t) for name, t in times.items()}


def matmul_runner(shapes, reduce, runs: int = 8, dtype=jnp.float32, precision=None):
  """Zero-arg callable: seconds per flop, reduce (min: peak, mean: sustained) over runs of each [m,k]@[k,n]."""
  timers = []
  for m, k, n in shapes:
    a = random.normal(random.PRNGKey(0), (m, k)).astype(dtype)
    b = random.normal(random.PRNGKey(1), (k, n)).astype(dtype)
    f = jax.jit(functools.partial(jnp.matmul, precision=precision))
    block(f(a, b))
    timers.append((functools.partial(f, a, b), 2 * m * k * n))
  return lambda: min(reduce([timed(lambda: block(f())) for _ in range(runs)]) / flops
                     for f, flops in timers)


def step_runner(config, model, batch, compiler_options=None):
  """(zero-arg callable returning one step's seconds, [state, stats], flops.compiled_cost of the step).

  The step is compiled once, with XLA compiler_options (e.g. {'xla_gpu_enable_cublaslt': True}) where given.
  """
  _, state = ts.create_train_state(config, random.PRNGKey(0), batch.rays)
  key = random.PRNGKey(1)
  xla = flops.compiled_cost(ts.make_train_step(config, model), state, batch, key,
                            compiler_options=compiler_options)
  step = xla['compiled']
  holder = list(block(step(state, batch, key)))

  def run():
    start = time.perf_counter()
    holder[:] = block(step(holder[0], batch, key))
    return time.perf_counter() - start
  return run, holder, xla


def dtu_like_rays(num_rays: int, seed: int = 0) -> rays_lib.Rays:
  """Rays [num_rays, ...] from a camera 2 units from the origin, DTU near/far."""
  rng = np.random.default_rng(seed)
  directions = np.concatenate([rng.uniform(-0.3, 0.3, (num_rays, 2)), np.ones((num_rays, 1))], -1)
  ones = np.ones((num_rays, 1))
  rays = rays_lib.Rays(np.zeros((num_rays, 3)) + [0., 0., -1.], directions,
                       directions / np.linalg.norm(directions, axis=-1, keepdims=True),
                       ones * 1e-3, ones, ones * 0.5, ones * 3.5)
  return rays_lib.map_rays(lambda x: jnp.asarray(x, jnp.float32), rays)


def dtu_like_batch(num_rays: int) -> batching.Batch:
  """A training Batch without data: dtu_like_rays [num_rays, ...] and uniform colours [num_rays, 3]."""
  return batching.Batch(rays=dtu_like_rays(num_rays),
                        rgb=jnp.asarray(np.random.default_rng(1).uniform(size=(num_rays, 3)), jnp.float32))


def with_patches(batch: batching.Batch, config) -> batching.Batch:
  """batch with RegNeRF's random-pose patches [P, ps, ps, ...] (P = batch_size_random // ps**2 DTU-like rays) when
  Config asks for depth smoothness, else batch as it is."""
  if not random_poses.needs_patches(config):
    return batch
  size = config.patch_size
  rays = dtu_like_rays(config.batch_size_random // size**2 * size**2, seed=3)
  return batch._replace(patch_rays=rays_lib.map_rays(lambda x: x.reshape((-1, size, size, x.shape[-1])), rays))


def render_runner(render_fn, num_rays: int, chunk: int):
  """Zero-arg callable returning the seconds to render num_rays rays in chunks (compiled here)."""
  rays = dtu_like_rays(num_rays, seed=2)
  block(render_fn(rays_lib.map_rays(lambda x: x[:chunk], rays)))
  return lambda: timed(lambda: inference.render_image(render_fn, rays, chunk))
