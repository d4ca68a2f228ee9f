"""Data parallelism with jax.sharding: rays split over devices, parameters replicated.

The mesh spans the devices of every process (jax.distributed); each process holds the same host values and
places only the slices that belong to its own devices, so the global arrays equal those of a single process.
"""

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def data_mesh(devices=None) -> Mesh:
  """A 1-D mesh named 'data' over the given (default: all, of every process) devices."""
  return Mesh(np.array(devices if devices is not None else jax.devices()), ('data',))


def _place(tree, sharding: NamedSharding):
  """Global arrays of the host values of tree (the same in every process) with the given sharding."""
  def place(x):
    host = np.asarray(x)
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])
  return jax.tree.map(place, jax.device_get(tree))


def shard_batch(batch, mesh: Mesh):
  """Places every [B, ...] leaf of batch split along B over the mesh's 'data' axis."""
  return _place(batch, NamedSharding(mesh, PartitionSpec('data')))


def replicate(tree, mesh: Mesh):
  """Places every leaf of tree whole on every device of the mesh."""
  return _place(tree, NamedSharding(mesh, PartitionSpec()))


def local_copy(tree):
  """Every leaf of a replicated tree as the copy on this process's first device (for process-local work)."""
  return jax.tree.map(lambda x: x.addressable_data(0), tree)
