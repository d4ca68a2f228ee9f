"""XLA's flop count (and memory estimate) of compiled programs, and of one train step of a config."""

import jax
from jax import random

from internal import datasets
from internal.training import train_step as train_step_lib


def compiled_cost(jitted, *args) -> dict:
  """XLA's {'flops', 'bytes', 'hlo'} of jitted compiled for args (nan where the backend reports none).

  'bytes' is XLA's estimate of the program's memory: arguments + outputs + temporaries - aliased; 'hlo' the
  compiled module's text (operations with their source locations, for profiles).
  """
  compiled = jitted.lower(*args).compile()
  cost = compiled.cost_analysis()
  cost = cost[0] if isinstance(cost, list) else cost
  memory = compiled.memory_analysis()
  return {'flops': float((cost or {}).get('flops', float('nan'))),
          'bytes': float('nan') if memory is None else float(
              memory.argument_size_in_bytes + memory.output_size_in_bytes + memory.temp_size_in_bytes
              - memory.alias_size_in_bytes),
          'hlo': compiled.as_text()}


def compiled_flops(jitted, *args) -> float:
  """XLA's flop count of jitted compiled for args (nan when the backend reports none)."""
  return compiled_cost(jitted, *args)['flops']


def train_step_flops(config) -> float:
  """XLA's flop count of one train step of Config's model and batch, compiled for one device."""
  batch = datasets.make_batcher(datasets.load_dataset('train', config), config)(1)
  model, state = train_step_lib.create_train_state(config, random.PRNGKey(0),
                                                   jax.tree.map(lambda x: x[:8], batch['rays']))
  return compiled_flops(train_step_lib.make_train_step(config, model), state, batch, random.PRNGKey(1))
