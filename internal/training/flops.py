"""Flop counts of traced programs (the lowered, uncompiled step) and XLA's memory estimate of compiled ones.

Flops are counted before compilation: after it, XLA's GPU backend counts each cuBLAS custom call as -1 flop, so a
compiled module's count falls short of the algebra and moves with the matmul precision (jax issues #16008, #20184,
#22249). A GPU's lowered program reports no count at all (jax 0.11.2 on an H100), so the program is lowered for
the CPU, whose count of the same algebra serves every backend.
"""

import warnings

import jax
from jax.sharding import SingleDeviceSharding
from jax import random

from internal import datasets
from internal.training import train_step as train_step_lib


def lowered_flops(jitted, *args) -> float:
  """Flops of jitted traced for args' shapes, counted on the program lowered for the CPU (uncompiled); nan when
  none is reported."""
  cpu = SingleDeviceSharding(jax.devices('cpu')[0])
  shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=cpu), args)
  with warnings.catch_warnings():  # Nothing runs, so donated arguments are never used: no warning about them.
    warnings.filterwarnings('ignore', 'Some donated buffers were not usable')
    cost = jitted.lower(*shapes).cost_analysis()
  cost = cost[0] if isinstance(cost, list) else cost
  return float((cost or {}).get('flops', float('nan')))


def compiled_cost(jitted, *args, compiler_options=None) -> dict:
  """{'flops' (lowered_flops), 'bytes', 'hlo', 'compiled'} of jitted compiled for args with XLA compiler_options.

  'bytes' is XLA's estimate of the program's memory: arguments + outputs + temporaries - aliased; 'hlo' the
  compiled module's text (operations with their source locations, for profiles); 'compiled' the callable.
  """
  lowered = jitted.lower(*args)
  compiled = lowered.compile(compiler_options=compiler_options) if compiler_options else lowered.compile()
  memory = compiled.memory_analysis()
  return {'flops': lowered_flops(jitted, *args),
          'bytes': float('nan') if memory is None else float(
              memory.argument_size_in_bytes + memory.output_size_in_bytes + memory.temp_size_in_bytes
              - memory.alias_size_in_bytes),
          'hlo': compiled.as_text(), 'compiled': compiled}


def train_step_flops(config) -> float:
  """Flops of one train step of Config's model and batch (lowered_flops)."""
  batch = datasets.make_batcher(datasets.load_dataset('train', config), config)(1)
  model, state = train_step_lib.create_train_state(config, random.PRNGKey(0),
                                                   jax.tree.map(lambda x: x[:8], batch.rays))
  return lowered_flops(train_step_lib.make_train_step(config, model), state, batch, random.PRNGKey(1))
