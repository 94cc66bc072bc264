"""Failed ensemble members: which members failed, what the update does with them, and when a search stops.

A member *fails* when its forward output is not finite or reaches the penalty (the thesis scores a diverged
simulation with 1000). Three policies (``Failure.kind``):

* ``"penalty"`` (the thesis): non-finite outputs are replaced by the penalty and every member enters the update;
* ``"resample"`` (EnsembleKalmanProcesses.jl's ``SampleSuccGauss``): the statistics use the successful members
  only, and the failed ones are redrawn from the Gaussian of the updated successful members;
* ``"ignore"`` (EnsembleKalmanProcesses.jl's "ignore failures" with a floor): the statistics use the successful
  members only, and the failed ones are left where they are.

Every iteration the search counts its successes. With fewer than ``min_success`` the ensemble is left unchanged
(a *skipped* iteration); after more than ``patience`` skipped iterations in a row the state's status becomes
``TOO_FEW_SUCCESSES`` and the loop ends there (``patience=0``: at the first such iteration). An update whose
result is not finite is never applied: the status becomes ``NOT_FINITE``. The host-side runner turns a status
into ``SearchStopped``, whose message is one line.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from jaxdip.engine.checks import check_choice, check_int, check_positive
from jaxdip._public import public_dir

__all__ = ["OK", "TOO_FEW_SUCCESSES", "NOT_FINITE", "STATUS_NAMES", "Failure", "sanitize", "successes",
           "SearchStopped", "status_message"]
__dir__ = public_dir(globals())

OK, TOO_FEW_SUCCESSES, NOT_FINITE = 0, 1, 2
STATUS_NAMES = {OK: "ok", TOO_FEW_SUCCESSES: "too_few_successes", NOT_FINITE: "not_finite"}


class Failure(NamedTuple):
    """How an update treats failed members (see the module docstring)."""

    kind: str = "penalty"
    min_success: int = 2
    patience: int = 0
    penalty: float = 1000.0

    def check(self) -> "Failure":
        check_choice("Failure", "kind", self.kind, ("penalty", "resample", "ignore"))
        check_int("Failure", "min_success", self.min_success, minimum=0 if self.kind == "penalty" else 2)
        check_int("Failure", "patience", self.patience, minimum=0)
        check_positive("Failure", "penalty", self.penalty, allow_inf=True)
        return self


def sanitize(Y: jnp.ndarray, penalty: float) -> jnp.ndarray:
    """``Y`` with every non-finite entry replaced by ``penalty``."""
    return jnp.where(jnp.isfinite(Y), Y, penalty)


def successes(Y: jnp.ndarray, penalty: float) -> jnp.ndarray:
    """(J,) bool: the members whose outputs are all finite and below ``penalty``."""
    return jnp.all(jnp.isfinite(Y) & (Y < penalty), axis=1)


def status_message(status: int, iteration: int, n_ok: int, failure: Failure) -> str:
    """The one-line reason a search stopped with ``status`` after ``iteration`` iterations."""
    if status == TOO_FEW_SUCCESSES:
        return (f"ensemble search stopped at iteration {iteration}: {n_ok} member(s) succeeded, fewer than "
                f"min_success={failure.min_success} in {failure.patience + 1} iteration(s) in a row; widen or "
                "move the initial ensemble, or relax the failure bound")
    if status == NOT_FINITE:
        return (f"ensemble search stopped at iteration {iteration}: the update was not finite (a singular "
                "covariance or overflowing outputs); the last finite ensemble is kept")
    return f"ensemble search status {status} at iteration {iteration}"


class SearchStopped(ArithmeticError):
    """A search ended early on a status other than OK; ``state`` is the last state (finite members)."""

    def __init__(self, message: str, status: int, state=None, history=None):
        super().__init__(message)
        self.key = "search"
        self.why = message
        self.status = status
        self.state = state
        self.history = history
