"""The closed-loop engine: roles as equinox Modules, ``simulate`` (one trajectory, pure), metric reducers, and
the ``monte_carlo`` driver. See docs/engine.md. Everything here is re-exported flat from ``jaxdip``."""

from jaxdip.engine import metrics
from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.engine.keys import split_lanes
from jaxdip.engine.roles import (
    Actuator, Controller, DiscretePlant, Estimator, FanOut, FanOutAux, Identity, Passthrough,
    Plant, Sensor, linearize, param,
)
from jaxdip.engine.simulate import (
    RESULTS, Aux, KeySchedule, Loop, Sample, Solution, State, init_state, simulate, with_precision,
)
from jaxdip.engine.driver import Ball, Gaussian, Rollout, device_mesh, monte_carlo
from jaxdip.engine.function_plant import FunctionPlant
from jaxdip.engine.summary import MetricSummary, Summary, summary
from jaxdip.engine.dataset import to_dataset

from jaxdip._public import public_dir

__all__ = [
    "metrics", "Actuator", "Controller", "DiscretePlant", "Estimator", "FanOut", "FanOutAux", "Identity",
    "Passthrough", "Plant", "Sensor", "linearize", "param", "RESULTS", "Aux",
    "KeySchedule", "Loop", "split_lanes",
    "Sample", "Solution", "State", "init_state", "simulate", "with_precision", "Ball", "Rollout", "device_mesh", "monte_carlo",
    "Gaussian", "FunctionPlant", "MetricSummary", "Summary", "summary", "ArgumentError", "ArgumentTypeError",
    "to_dataset",
]
__dir__ = public_dir(globals())
