"""jaxdip: differentiable, vectorised estimation and control of underactuated pendulums.

Importing jaxdip turns on JAX's float64 mode (``jax_enable_x64``) for the whole process, before any array is
made: the documents' methods need it (P with singular values near 1e6, MHE weights of order 1e4). Code that
wants float32 passes explicit float32 arrays; nothing in jaxdip silently downcasts.

The public namespace is flat (``import jaxdip as jd``): the engine (``jd.simulate``, ``jd.monte_carlo``,
``jd.Loop``, ``jd.Rollout``, the roles ``jd.Plant``, ``jd.Sensor``, ... and ``jd.metrics``) and the
subpackages ``jd.plants``, ``jd.sensors``, ``jd.estimators``, ``jd.control``. See docs/engine.md.
"""

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

from jaxdip import plants, sim  # noqa: E402,F401
from jaxdip import control, estimators  # noqa: E402,F401
from jaxdip.engine import (  # noqa: E402,F401
    RESULTS, Actuator, Aux, Ball, Controller, DiscretePlant, Estimator, FanOut, FanOutAux, Identity, KeySchedule,
    Loop, Passthrough, Plant, Rollout, Sample, Sensor, Solution, State, init_state, linearize,
    metrics, monte_carlo, param, simulate, split_lanes,
)
from jaxdip.sim import sensors  # noqa: E402,F401
from jaxdip.sim.discretize import Discrete, zoh  # noqa: E402,F401
