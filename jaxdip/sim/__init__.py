"""Simulation core: integration, discretisation, sensors, actuators, the closed loop and Monte Carlo."""

from jaxdip.sim import actuators, montecarlo, sensors
from jaxdip.sim.component import Component, chain, identity, stateless
from jaxdip.sim.discretize import Discrete, linearize, linearize_discrete, zoh
from jaxdip.sim.integrate import make_period_map, rk4_step, rk4_zoh
from jaxdip.sim.loop import Carry, Loop, LoopParams, Record, Stats, advance, init_carry, rollout

__all__ = [
    "actuators", "montecarlo", "sensors", "Component", "chain", "identity", "stateless", "Discrete",
    "linearize", "linearize_discrete", "zoh", "make_period_map", "rk4_step", "rk4_zoh", "Carry", "Loop",
    "LoopParams", "Record", "Stats", "advance", "init_carry", "rollout",
]
