"""When an estimator's output is taken and where it starts: wrappers, the one mechanism for both.

An estimator computes its current estimate (its output) and starts from its own ``xhat0`` field (estimators
without one start from what they read: the LDF from the measured positions, the continuous observers from y_0).
The wrappers change that, never what the estimator computes:

Where it starts (``init`` replaces ``xhat0`` of the innermost estimator that has one):
  ``FromTruth(inner)``         from x0, the true initial state handed to ``init``;
  ``InitialError(inner, std)`` from x0 + std * N(0, I), drawn from the init key. Estimators that receive the same
                               init key (the members of a ``FanOut``) start from the same perturbed estimate.

When its output is taken (at sample j, which brings y_j and u_{j-1}):
  ``Prior(inner)``   x_{j|j-1}, the one-step prediction made with u_{j-1} before y_j (``aux.prior`` of the
                     Kalman-type filters; their starting estimate at j = 0);
  ``Ahead(inner)``   x_{j+1|j}, the prediction of the next state with the input u_{j-1} held (``aux.ahead`` of the
                     proximal MHEs): what a controller computing u_j should act on;
  ``Delayed(inner)`` the inner output of sample j - 1 (at j = 0: the x0 given to ``init``). For a predictor whose
                     output at j is its estimate of x_{j+1}, the delayed output at j is its estimate of x_j made
                     one sample earlier, the quantity to compare with x_j;
  ``DelayedMeasurement(inner, y_init)`` the inner estimator fed y_{j-1} instead of y_j (``y_init`` at j = 0).

Every wrapper's ``aux`` is ``inner``'s aux of the current sample.
"""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, param, dtype_of


from jaxdip._public import public_dir

__all__ = ["started_at", "FromTruth", "InitialError", "Prior", "Ahead", "Delayed", "DelayedMeasurement"]
__dir__ = public_dir(globals())


def started_at(est, x):
    """``est`` with the ``xhat0`` of its innermost estimator that has one replaced by ``x``."""
    if hasattr(est, "xhat0"):
        return eqx.tree_at(lambda e: e.xhat0, est, x)
    if hasattr(est, "inner"):
        return eqx.tree_at(lambda e: e.inner, est, started_at(est.inner, x))
    raise TypeError(f"{type(est).__name__} has no starting estimate xhat0 to set")


def _check_inner(self) -> None:
    # a wrapper around something that is not an estimator fails at the first step, deep inside the scan
    if not (callable(getattr(self.inner, "init", None)) and callable(getattr(self.inner, "step", None))):
        raise checks.ArgumentTypeError(f"{type(self).__name__}: inner must be an estimator (init and step), "
                                       f"got {type(self.inner).__name__}")
    if isinstance(getattr(self, "std", None), jax.Array):
        checks.check_scalar_or_vector(self, "std", self.std, why="(one std for every state, or one per state)")
        checks.check_nonnegative(self, "std", self.std)


def _inner_sizes(self) -> dict:
    # a wrapper reads and hands on what its inner estimator does (a delay or another output of the same size)
    sizes = getattr(self.inner, "io_sizes", None)
    return sizes() if callable(sizes) else {}


class FromTruth(Estimator):
    """``inner`` started from the true initial state x0."""

    inner: Any

    __check_init__ = _check_inner
    io_sizes = _inner_sizes

    def init(self, key, x0):
        x0 = jnp.asarray(x0, dtype=dtype_of(x0))
        return started_at(self.inner, x0).init(key, x0)

    def step(self, state, y, u_prev, key, k):
        return self.inner.step(state, y, u_prev, key, k)


class InitialError(Estimator):
    """``inner`` started from x0 + std * N(0, I) drawn from the init key."""

    inner: Any
    std: jax.Array = param()

    __check_init__ = _check_inner
    io_sizes = _inner_sizes

    def init(self, key, x0):
        x0 = jnp.asarray(x0, dtype=dtype_of(x0))
        x = x0 + self.std * jax.random.normal(key, x0.shape, x0.dtype)
        return started_at(self.inner, x).init(key, x)

    def step(self, state, y, u_prev, key, k):
        return self.inner.step(state, y, u_prev, key, k)


class _AuxOutput(Estimator):
    """``inner`` unchanged, its output replaced by one field of its aux (named by the subclass's ``field``)."""

    inner: Any
    field: ClassVar[str]

    __check_init__ = _check_inner
    io_sizes = _inner_sizes

    def init(self, key, x0):
        return self.inner.init(key, x0)

    def step(self, state, y, u_prev, key, k):
        state, _, aux = self.inner.step(state, y, u_prev, key, k)
        return state, getattr(aux, self.field), aux


class Prior(_AuxOutput):
    """The output of ``inner`` is its one-step prediction x_{j|j-1} (``aux.prior``)."""

    field = "prior"


class Ahead(_AuxOutput):
    """The output of ``inner`` is its prediction of the next state with the input held (``aux.ahead``)."""

    field = "ahead"


class Delayed(Estimator):
    """The output of ``inner`` held for one sample; the initial output is the x0 given to ``init``."""

    inner: Any

    __check_init__ = _check_inner
    io_sizes = _inner_sizes

    def init(self, key, x0):
        x0 = jnp.asarray(x0, dtype=dtype_of(x0))
        return self.inner.init(key, x0), x0

    def step(self, state, y, u_prev, key, k):
        inner_state, held = state
        inner_state, out, aux = self.inner.step(inner_state, y, u_prev, key, k)
        return (inner_state, out), held, aux


class DelayedMeasurement(Estimator):
    """``inner`` fed the previous sample's measurement: y_{j-1} at sample j, ``y_init`` at j = 0."""

    inner: Any
    y_init: jax.Array = param()

    __check_init__ = _check_inner
    io_sizes = _inner_sizes

    def init(self, key, x0):
        return self.inner.init(key, x0), self.y_init

    def step(self, state, y, u_prev, key, k):
        inner_state, y_prev = state
        inner_state, out, aux = self.inner.step(inner_state, y_prev, u_prev, key, k)
        return (inner_state, jnp.asarray(y, jnp.float64)), out, aux
