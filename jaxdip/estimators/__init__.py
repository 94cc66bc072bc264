"""Estimators of the common init/step interface (``jaxdip.sim.component``)."""

from jaxdip.estimators.passthrough import passthrough

__all__ = ["passthrough"]
