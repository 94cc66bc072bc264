"""Plant models, each an engine plant (``jaxdip.Plant`` or ``jaxdip.DiscretePlant``) with its constants as array
fields."""

from jaxdip.plants import dip, examples2d, lorenz, rwp, trig, twip
from jaxdip.plants.dip import DIP
from jaxdip.plants.lorenz import Lorenz
from jaxdip.plants.rwp import RWP
from jaxdip.plants.twip import TWIP

from jaxdip._public import public_dir

__all__ = ["DIP", "Lorenz", "RWP", "TWIP", "dip", "examples2d", "lorenz", "rwp", "trig", "twip"]
__dir__ = public_dir(globals())
