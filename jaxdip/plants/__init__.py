"""Plant models, each a ``Plant`` bundle of pure functions over a parameter pytree."""

from jaxdip.plants import dip, examples2d, lorenz, rwp, twip
from jaxdip.plants.base import Plant
from jaxdip.plants.dip import DIP
from jaxdip.plants.lorenz import Lorenz
from jaxdip.plants.rwp import RWP

__all__ = ["Plant", "DIP", "Lorenz", "RWP", "dip", "examples2d", "lorenz", "rwp", "twip"]
