"""Simulation pieces around the engine: sensors, actuators, input disturbances and exact discretisation (the
closed loop, the Monte Carlo driver and RK4 are ``jaxdip.engine``)."""

from jaxdip.sim import actuators, sensors
from jaxdip.sim.discretize import Discrete, sample, zoh

from jaxdip._public import public_dir

__all__ = ["actuators", "sensors", "Discrete", "zoh", "sample"]
__dir__ = public_dir(globals())
