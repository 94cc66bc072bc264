"""Step-size schedules of an ensemble Kalman search: how far each update moves in algorithmic time.

An update with step ``dt`` uses the noise covariance ``R / dt`` (and perturbations scaled by ``1 / sqrt(dt)``),
as EnsembleKalmanProcesses.jl does; ``dt = 1`` is the thesis's update (2.22). A schedule is a ``Schedule``:
``step(iteration, time, Y, ok, y, R) -> dt`` and the algorithmic time ``end`` at which the search is done
(``inf``: run to the iteration budget).

* ``fixed(dt)``: the same step every iteration (the thesis: ``fixed(1.0)``);
* ``scheduled(fn)``: ``dt = fn(iteration)``, any traceable function (a decay, a warm-up);
* ``data_misfit(end=1.0)``: the data-misfit controller of Iglesias & Yang (2021), with
  ``Phi_j = 1/2 |R^-1/2 (Y_j - y)|^2`` over the successful members and ``M`` observations,
  ``dt = min(max(M / (2 mean Phi), sqrt(M / (2 var Phi))), end - time)``, so the algorithmic time reaches
  ``end`` exactly and the search stops there (no hand-tuned iteration count).
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import jax.numpy as jnp

from jaxdip.engine.checks import check_positive
from jaxdip._public import public_dir

__all__ = ["Schedule", "fixed", "scheduled", "data_misfit", "misfits"]
__dir__ = public_dir(globals())


class Schedule(NamedTuple):
    step: Callable  # (iteration, time, Y (J, m), ok (J,), y (m,), R (m, m)) -> dt
    end: float = math.inf
    name: str = "custom"


def fixed(dt: float = 1.0) -> Schedule:
    """The same step ``dt`` every iteration."""
    check_positive("fixed", "dt", dt)
    return Schedule(lambda i, t, Y, ok, y, R: dt, math.inf, "fixed")


def scheduled(fn: Callable) -> Schedule:
    """``dt = fn(iteration)`` (``iteration`` an int32 array; ``fn`` traceable)."""
    return Schedule(lambda i, t, Y, ok, y, R: fn(i), math.inf, "scheduled")


def misfits(Y: jnp.ndarray, y: jnp.ndarray, R: jnp.ndarray) -> jnp.ndarray:
    """(J,) ``Phi_j = 1/2 (Y_j - y)^T R^-1 (Y_j - y)``."""
    L = jnp.linalg.cholesky(R)
    z = jnp.linalg.solve(L, (Y - y).T)  # L^-1 (Y_j - y): |z|^2 = (Y_j - y)^T R^-1 (Y_j - y)
    return 0.5 * jnp.sum(z * z, axis=0)


def data_misfit(end: float = 1.0) -> Schedule:
    """The data-misfit controller (Iglesias & Yang 2021): adaptive steps that sum to ``end`` exactly."""
    check_positive("data_misfit", "end", end)

    def step(i, t, Y, ok, y, R):
        M = Y.shape[1]
        w = ok.astype(Y.dtype)
        n = jnp.maximum(w.sum(), 2.0)
        phi = jnp.where(ok, misfits(Y, y, R), 0.0)  # a failed member's misfit may be inf
        mean = jnp.sum(w * phi) / n
        var = jnp.sum(w * (phi - mean) ** 2) / (n - 1)
        q = jnp.maximum(M / (2.0 * mean), jnp.sqrt(M / (2.0 * var)))
        return jnp.minimum(q, end - t)

    return Schedule(step, float(end), "data_misfit")
