"""The checks a ``Loop`` runs when it is built: its parts against each other (the sizes each part knows from its
fields, ``io_sizes``) and the loop's own numbers, before anything is traced."""

from __future__ import annotations

import numbers

from jaxdip.engine import checks
from jaxdip.engine.roles import SAME, Plant

from jaxdip._public import public_dir

__all__ = ["PRECISIONS", "check_loop"]
__dir__ = public_dir(globals())

PRECISIONS = ("float64", "float32")  # what ``Loop.precision`` may be


def _sizes(c) -> dict:
    sizes = getattr(c, "io_sizes", None)
    return sizes() if callable(sizes) else {}


def _count(k, noun: str) -> str:
    return f"{k} {noun}" if k == 1 else f"{k} {noun}s"


def _part(role: str, c) -> str:
    return f"the {role} {type(c).__name__}"


def check_loop(loop) -> None:
    """The parts of a loop against each other (sizes each part knows from its fields: ``io_sizes``), and the
    loop's own numbers. Run when the loop is built, before anything is traced."""
    plant = loop.plant
    if not isinstance(plant, Plant):
        raise checks.ArgumentTypeError(f"Loop: plant must be a jaxdip Plant (or DiscretePlant), "
                                       f"got {type(plant).__name__}")
    # the other roles are duck-typed (``Identity`` is a full-state sensor as well as the ideal actuator): a part
    # needs init and step
    for role, c in (("sensor", loop.sensor), ("estimator", loop.estimator), ("controller", loop.controller),
                    ("actuator", loop.actuator)):
        if not (callable(getattr(c, "init", None)) and callable(getattr(c, "step", None))):
            raise checks.ArgumentTypeError(f"Loop: {role} must be a component with init and step (a jaxdip "
                                           f"{role.capitalize()}), got {type(c).__name__}")
    if isinstance(loop.dt, bool) or not isinstance(loop.dt, numbers.Real) or not (0 < loop.dt < float("inf")):
        checks.fail("Loop", f"dt must be a positive finite number of seconds, got {loop.dt!r}")
    checks.check_int("Loop", "substeps", loop.substeps, 1)
    checks.check_choice("Loop", "precision", loop.precision, PRECISIONS)
    n, m = plant.n, plant.m
    pname = f"the plant {type(plant).__name__}"
    for name, v in (("process_noise_std", loop.process_noise_std), ("state_bound", loop.state_bound),
                    ("norm_bound", loop.norm_bound)):
        if v is None:
            continue
        if checks.shape_of(v) not in ((), (n,)) and name != "norm_bound":
            checks.fail("Loop", f"{name} must be a scalar or ({n},) for {pname} ({n} states), "
                        f"got {checks.fmt_shape(checks.shape_of(v))}")
        if name == "process_noise_std":
            checks.check_nonnegative("Loop", name, v)
        else:
            checks.check_positive("Loop", name, v, allow_inf=True)

    def mismatch(what_a, size_a, why_a, what_b, size_b, why_b):
        a = f" ({why_a})" if why_a else ""
        b = f" ({why_b})" if why_b else ""
        checks.fail("Loop", f"{what_a} {size_a}{a} but {what_b} {size_b}{b}")

    sens = _sizes(loop.sensor)
    if "in" in sens and sens["in"][0] != n:
        mismatch(f"{_part('sensor', loop.sensor)} reads", _count(sens['in'][0], "state"), sens["in"][1],
                 f"{pname} has", _count(n, "state"), "")
    p, p_why = sens.get("out", (None, ""))
    if p == SAME:
        p, p_why = n, "a full-state sensor"
    est = _sizes(loop.estimator)
    if "in" in est and p is not None and est["in"][0] != p:
        mismatch(f"{_part('sensor', loop.sensor)} gives", _count(p, "output"), p_why,
                 f"{_part('estimator', loop.estimator)} expects", _count(est['in'][0], "measurement"), est["in"][1])
    if "u" in est and est["u"][0] != m:
        mismatch(f"{pname} has", _count(m, "input"), "", f"{_part('estimator', loop.estimator)} expects",
                 _count(est['u'][0], "input"), est["u"][1])
    nh, nh_why = est.get("out", (None, ""))
    if nh == SAME:
        nh, nh_why = (p, p_why) if p is not None else (est["in"] if "in" in est else (None, ""))
    ctrl = _sizes(loop.controller)
    if "in" in ctrl and nh is not None and ctrl["in"][0] != nh:
        mismatch(f"{_part('estimator', loop.estimator)} gives", _count(nh, "estimated state"), nh_why,
                 f"{_part('controller', loop.controller)} expects", _count(ctrl['in'][0], "state"), ctrl["in"][1])
    if "out" in ctrl and ctrl["out"][0] not in (SAME, m):
        mismatch(f"{_part('controller', loop.controller)} gives", _count(ctrl['out'][0], "input"), ctrl["out"][1],
                 f"{pname} has", _count(m, "input"), "")
    act = _sizes(loop.actuator)
    for key in ("in", "out"):
        if key in act and act[key][0] not in (SAME, m):
            mismatch(f"{_part('actuator', loop.actuator)} {'reads' if key == 'in' else 'gives'}",
                     _count(act[key][0], "input"), act[key][1], f"{pname} has", _count(m, "input"), "")
