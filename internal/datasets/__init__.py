"""Scene loaders (DTU, LLFF, Blender, captures, packed and generated scenes) and training batches."""

from internal.datasets.base import Dataset, DatasetError, DatasetNotFoundError
from internal.datasets.batching import make_batcher
from internal.datasets.loader import load_dataset, render_path_rays

__all__ = ['Dataset', 'DatasetError', 'DatasetNotFoundError', 'load_dataset', 'make_batcher', 'render_path_rays']
