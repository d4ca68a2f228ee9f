"""Data parallelism with jax.sharding: rays split over devices, parameters replicated."""

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def data_mesh(devices=None) -> Mesh:
  """A 1-D mesh named 'data' over the given (default: all) devices."""
  return Mesh(np.array(devices if devices is not None else jax.devices()), ('data',))


def shard_batch(batch, mesh: Mesh):
  """Places every [B, ...] leaf of batch split along B over the mesh's 'data' axis."""
  return jax.device_put(batch, NamedSharding(mesh, PartitionSpec('data')))


def replicate(tree, mesh: Mesh):
  """Places every leaf of tree whole on every device of the mesh."""
  return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))
