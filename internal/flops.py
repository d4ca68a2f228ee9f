"""XLA's flop count of compiled programs, and of one train step of a config."""

import jax
from jax import random

from internal import datasets
from internal import train_step as train_step_lib


def compiled_flops(jitted, *args) -> float:
  """XLA's flop count of jitted compiled for args (nan when the backend reports none)."""
  cost = jitted.lower(*args).compile().cost_analysis()
  cost = cost[0] if isinstance(cost, list) else cost
  return float((cost or {}).get('flops', float('nan')))


def train_step_flops(config) -> float:
  """XLA's flop count of one train step of Config's model and batch, compiled for one device."""
  batch = datasets.make_batcher(datasets.load_dataset('train', config), config)(1)
  model, state = train_step_lib.create_train_state(config, random.PRNGKey(0),
                                                   jax.tree.map(lambda x: x[:8], batch['rays']))
  return compiled_flops(train_step_lib.make_train_step(config, model), state, batch, random.PRNGKey(1))
