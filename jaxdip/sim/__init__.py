"""Simulation pieces around the engine: integration, discretisation, sensors and actuators (the closed loop and
the Monte Carlo driver are ``jaxdip.engine``)."""

from jaxdip.sim import actuators, sensors
from jaxdip.sim.component import Component, chain, identity, stateless
from jaxdip.sim.discretize import Discrete, linearize, linearize_discrete, zoh
from jaxdip.sim.integrate import make_period_map, rk4_step, rk4_zoh

__all__ = [
    "actuators", "sensors", "Component", "chain", "identity", "stateless", "Discrete",
    "linearize", "linearize_discrete", "zoh", "make_period_map", "rk4_step", "rk4_zoh",
]
