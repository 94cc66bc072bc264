"""jaxdip: differentiable, vectorised estimation and control of underactuated pendulums.

Importing jaxdip turns on JAX's float64 mode (``jax_enable_x64``) for the whole process, before any array is
made: the documents' methods need it (P with singular values near 1e6, MHE weights of order 1e4). Code that
wants float32 passes explicit float32 arrays; nothing in jaxdip silently downcasts.

The public namespace is flat (``import jaxdip as jd``): the engine (``jd.simulate``, ``jd.monte_carlo``,
``jd.Loop``, ``jd.Rollout``, the roles ``jd.Plant``, ``jd.Sensor``, ... and ``jd.metrics``) and the
subpackages ``jd.plants``, ``jd.sensors``, ``jd.estimators``, ``jd.control``, ``jd.stats``; ``jd.summary`` reduces a
Monte Carlo result to means and intervals, ``jd.to_dataset`` labels its per-seed numbers (xarray, the
``data`` extra), ``jd.FunctionPlant`` makes a plant of a plain function. See docs/engine.md.
"""

from importlib import import_module as _import_module

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

# The namespace is re-exported lazily (PEP 562): each name's module is imported on first use, so importing one part
# of the library (the engine, jaxdip.xla_flags before JAX starts, the CLI's argument parser) imports no other, and
# no module depends on the package root: the layers (docs/architecture.md) hold for the imports Python runs too.
_SUBMODULES = {"control": "jaxdip.control", "engine": "jaxdip.engine", "estimators": "jaxdip.estimators",
               "plants": "jaxdip.plants", "sim": "jaxdip.sim", "sensors": "jaxdip.sim.sensors",
               "stats": "jaxdip.stats", "dataset": "jaxdip.dataset"}
_NAMES = {
    **dict.fromkeys((
        "RESULTS", "ArgumentError", "ArgumentTypeError", "Actuator", "Aux", "Ball", "Controller", "DiscretePlant", "Estimator", "FanOut", "FanOutAux",
        "FunctionPlant", "Identity", "KeySchedule", "Loop", "Passthrough", "Plant", "Rollout", "Sample", "Sensor",
        "Solution", "State", "Summary", "init_state", "linearize", "metrics", "monte_carlo", "param", "simulate", "with_precision",
        "split_lanes", "summary", "to_dataset"), "jaxdip.engine"),
    "run_estimator": "jaxdip.estimators.recorded", "EstimatorRun": "jaxdip.estimators.recorded",
    "read_csv": "jaxdip.runner.records", "write_csv": "jaxdip.runner.records",
    "Discrete": "jaxdip.sim.discretize", "zoh": "jaxdip.sim.discretize",
}
__all__ = sorted([*_SUBMODULES, *_NAMES])


def __getattr__(name: str):
    if name in _SUBMODULES:
        value = _import_module(_SUBMODULES[name])
    elif name in _NAMES:
        value = getattr(_import_module(_NAMES[name]), name)
    else:
        raise AttributeError(f"module 'jaxdip' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    # the public names only: not jax, the helpers above or what Python puts in every module (``__version__`` and
    # the other dunders stay reachable as attributes)
    return sorted(__all__)
