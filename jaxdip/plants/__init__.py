"""Plant models, each a ``Plant`` bundle of pure functions over a parameter pytree."""

from jaxdip.plants import dip, examples2d, lorenz, rwp, twip
from jaxdip.plants.base import Plant
from jaxdip.plants.dip import DIP

__all__ = ["Plant", "DIP", "dip", "examples2d", "lorenz", "rwp", "twip"]
