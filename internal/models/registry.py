"""The models `Config.model` chooses between; both share one call signature, outputs and training code."""

import flax.linen as nn

from internal.models import mip_nerf
from internal.models import nerf

# Config.model -> (model class, its MLP class, construct_model), each gin-configurable under its class name.
MODELS = {'mipnerf': (mip_nerf.MipNerfModel, mip_nerf.MLP, mip_nerf.construct_model),
          'nerf': (nerf.NerfModel, nerf.NerfMLP, nerf.construct_model)}


def _entry(name: str):
  """The MODELS entry of name; ValueError naming Config.model otherwise."""
  if name not in MODELS:
    raise ValueError(f'Config.model = {name!r}; expected one of {list(MODELS)}')
  return MODELS[name]


def build(name: str, **kwargs) -> nn.Module:
  """The gin-bound model `name` (unbound, no parameters), e.g. to read its encoding degrees."""
  return _entry(name)[0](**kwargs)


def gin_modules(name: str):
  """[(gin name, gin-bound instance)] of the model `name` and its MLP: the settings that define it."""
  model_cls, mlp_cls, _ = _entry(name)
  return [(mlp_cls.__name__, mlp_cls()), (model_cls.__name__, model_cls())]


def construct_model(name: str, key, example_rays, white_background: bool, precision: str = 'float32'):
  """(model, variables) of the model `name`, initialized on example rays [B, ...]."""
  return _entry(name)[2](key, example_rays, white_background, precision)
