"""What a loss term reads: a ray family of the batch as the model rendered it (training/renderer.py)."""

from typing import NamedTuple

from internal.rays import Rays


class Rendered(NamedTuple):
  """A ray family rendered once by the model: its rays as rendered (flat [R, C], near and far annealed), the
  renderings per level ({'rgb', 'distance_mean', 'acc', ...} [R, ...]) and each level's samples ({'weights', 'rgb',
  'density', 't_vals'}), and the family's shape of rays before flattening (e.g. [P, ps, ps])."""
  rays: Rays
  levels: list
  history: list
  shape: tuple

  def depths(self) -> list:
    """The rendered ray parameter t [*shape] per level (distance_mean)."""
    return [level['distance_mean'].reshape(self.shape) for level in self.levels]


def over_levels(config, values):
  """The sum of per-level values, the coarse ones times Config.coarse_loss_mult, as the data loss."""
  return values[-1] + config.coarse_loss_mult * sum(values[:-1])
