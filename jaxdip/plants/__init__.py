"""Plant models, each a ``Plant`` bundle of pure functions over a parameter pytree."""

from jaxdip.plants import dip, examples2d, lorenz, rwp, twip
from jaxdip.plants.base import Plant

__all__ = ["Plant", "dip", "examples2d", "lorenz", "rwp", "twip"]
