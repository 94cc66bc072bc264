"""The Kalman filter and the extended Kalman filter as engine estimators (the equations: ``jaxdip.estimators.kalman``).

Timing. Sample j brings y_j and u_{j-1}: from j = 1 on the filter predicts with u_{j-1}, then updates with y_j; at
j = 0 the prior is (xhat0, P0), so (xhat0, P0) is the prior of x_0 before y_0 is seen. The output is x+_j; ``aux``
is a ``GaussianAux`` (P+_j, the prediction x-_j and P-_j, log N(y_j; yhat_j, S_j)). Other output timings and
other starting estimates are the wrappers of ``jaxdip.estimators.wrappers`` (``Prior`` hands out x-_j,
``DelayedMeasurement`` feeds y_{j-1}, ``FromTruth``/``InitialError`` start from the true x_0).

Run over recorded data, the same step is the offline filter (``jaxdip.estimators.recorded.kalman_filter``); for
that use every matrix of ``KalmanFilter`` may also be a stack over time (leading axis T, natural indexing:
x_{j+1} = Phi[j] x_j + W[j] u_j + w_j, w_j ~ N(0, Q[j]); y_j = C[j] x_j + v_j, v_j ~ N(0, R[j]); entry T-1 of
Phi, W, Q is never used).

Missing measurements. With ``nan_missing=True`` a NaN component of y_j is missing: it is removed exactly
(``jaxdip.estimators.kalman.mask_measurement``), and a y_j that is all NaN makes sample j a pure prediction.
``R`` may be a scalar (r I), a vector (the diagonal) or a full matrix (``kalman.as_covariance``); a stack over
time is full, (T, p, p).
"""

from __future__ import annotations

from typing import Any, Callable, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, Plant, param, dtype_of, rhs
from jaxdip.estimators.kalman import GaussianAux, KFState, as_covariance, predict, update
from jaxdip.estimators.linearized import local_model


from jaxdip._public import public_dir

__all__ = ["KalmanFilter", "ExtendedKalmanFilter", "output_size"]
__dir__ = public_dir(globals())


def _at(a, j):
    """A time-invariant matrix, or entry j of a stack over time."""
    return a if a.ndim == 2 else a[j]


def _first_or(k, start: KFState, xp, Pp):
    first = k == 0
    return jnp.where(first, start.x, xp), jnp.where(first, start.P, Pp)


class _Gaussian(Estimator):
    """Shared by the KF and the EKF: ``_transition(x, u, j) -> (F, x_next)`` and ``_output(x) -> (H, yhat)``."""

    def init(self, key, x0):
        x = jnp.asarray(self.xhat0, dtype=dtype_of(x0))
        return KFState(x, jnp.asarray(self.P0, x.dtype))

    def step(self, state, y, u_prev, key, k):
        u = jnp.reshape(jnp.asarray(u_prev, state.x.dtype), (self.n_inputs,))
        j = jnp.maximum(k - 1, 0)  # the transition that brought x_{k-1} to x_k
        F, x_next = self._transition(state.x, u, j)
        xp, Pp = _first_or(k, state, *predict(state.x, state.P, F, x_next, _at(self.Q, j)))
        H, yhat = self._output(xp, k)
        observed = ~jnp.isnan(y) if self.nan_missing else None
        x, P, ll = update(xp, Pp, y, H, yhat, _at(self.R, k), self.jitter, observed)
        return KFState(x, P), x, GaussianAux(P, xp, Pp, ll)

    def transition_jacobian(self, x, u, j):
        """F_j at (x, u): what the Rauch-Tung-Striebel smoother needs."""
        return self._transition(x, jnp.reshape(u, (self.n_inputs,)), j)[0]


class KalmanFilter(_Gaussian):
    """KF for x_{k+1} = Phi x_k + W u_k + w, y_k = C x_k + v, w ~ (0, Q), v ~ (0, R) (module doc for the
    timing). ``jitter`` (static): see ``kalman.update``; ``nan_missing`` (static): NaN components of y are
    missing (module doc)."""

    Phi: jax.Array = param()
    W: jax.Array = param()
    C: jax.Array = param()
    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    jitter: float = eqx.field(default=0.0, static=True)
    nan_missing: bool = eqx.field(default=False, static=True)

    def __init__(self, Phi, W, C, Q, R, P0, xhat0=None, jitter: float = 0.0, nan_missing: bool = False):
        for name, v in (("Phi", Phi), ("W", W), ("C", C), ("Q", Q), ("R", R), ("P0", P0), ("xhat0", xhat0)):
            if v is not None:
                checks.check_real(self, name, v)
        checks.check_square(self, "Phi", Phi, leading=True)
        checks.check_ndim(self, "C", C, (2, 3), "a (p, n) output matrix (or a (T, p, n) stack over time)")
        self.Phi, self.C, self.Q, self.P0, self.jitter = Phi, C, Q, P0, jitter
        self.R, self.nan_missing = as_covariance(R, jnp.shape(C)[-2]), nan_missing
        d = jnp.shape(Phi)[-1]
        W = jnp.zeros((d, 1)) if W is None else jnp.asarray(W)
        if W.ndim <= 2:  # (d,) is one input; a stack over time (T, d, m) is checked once built
            checks.check_shape(self, "W", W, (d, None) if W.ndim == 2 else (d,), f"for a {d}-state model")
        self.W = jnp.reshape(W, (d, -1)) if W.ndim <= 2 else W
        self.xhat0 = jnp.zeros(d) if xhat0 is None else xhat0

    def __check_init__(self):
        d = self.Phi.shape[-1]
        why = f"for a {d}-state model"
        checks.check_shape(self, "W", self.W, (d, None), why, leading=True)
        checks.check_shape(self, "C", self.C, (None, d), why, leading=True)
        p = self.C.shape[-2]
        checks.check_covariance(self, "Q", self.Q, d, why, leading=True)
        checks.check_covariance(self, "R", self.R, p, f"for {p} measurements (C is {checks.fmt_shape(self.C.shape)})",
                                leading=True)
        checks.check_covariance(self, "P0", self.P0, d, why)
        checks.check_state_vector(self, "xhat0", self.xhat0, d, why)
        for name in ("Phi", "W", "C"):
            checks.check_finite(self, name, getattr(self, name))
        checks.check_nonnegative(self, "jitter", self.jitter)

    def io_sizes(self) -> dict:
        shape = checks.fmt_shape
        return {"in": (self.C.shape[-2], f"C is {shape(self.C.shape)}"),
                "out": (self.Phi.shape[-1], f"Phi is {shape(self.Phi.shape)}"),
                "u": (self.W.shape[-1], f"W is {shape(self.W.shape)}")}

    @property
    def n_inputs(self) -> int:
        return self.W.shape[-1]

    def _transition(self, x, u, j):
        Phi = _at(self.Phi, j)
        return Phi, Phi @ x + _at(self.W, j) @ u

    def _output(self, x, k):
        C = _at(self.C, k)
        return C, C @ x


def output_size(C, h: Optional[Callable], xhat0) -> int:
    """p: the rows of C, or the size of h(xhat0) (by shape evaluation, nothing computed)."""
    if C is not None:
        return int(jnp.shape(C)[-2])
    return int(jax.eval_shape(h, jnp.asarray(xhat0, jnp.result_type(float))).shape[0])


class ExtendedKalmanFilter(_Gaussian):
    """EKF for x_{k+1} = f(x_k, u_k) + w, y_k = h(x_k) + v (or C x_k + v).

    The transition is either a discrete map ``f(x, u)`` (static, compared by identity: pass a module-level
    function), linearised at x+ by forward-mode autodiff, or a continuous engine ``Plant`` ``model`` sampled
    every ``dt``: relinearised at x+ every sample (Jacobian and matrix exponential, ``local_model``;
    ``expm_squarings``: see ``linearized.expm_small``), the mean propagated by the same local affine model (the
    exponential-Euler step, exact for linear dynamics: the EKF of a linear model is the KF). The output is
    linear (array ``C``) or a map ``h(x)`` (static), linearised at the prediction. ``jitter``: see
    ``kalman.update``; ``R`` and ``nan_missing``: as in ``KalmanFilter``.
    """

    Q: jax.Array = param()
    R: jax.Array = param()
    P0: jax.Array = param()
    xhat0: jax.Array = param()
    C: Optional[jax.Array]
    model: Any
    f: Optional[Callable] = eqx.field(static=True)
    h: Optional[Callable] = eqx.field(static=True)
    dt: Optional[float] = eqx.field(static=True)
    n_inputs: int = eqx.field(static=True)
    expm_squarings: int = eqx.field(static=True)
    jitter: float = eqx.field(static=True)
    nan_missing: bool = eqx.field(default=False, static=True)

    def __init__(self, Q, R, P0, xhat0=None, *, model=None, dt: Optional[float] = None,
                 f: Optional[Callable] = None, C=None, h: Optional[Callable] = None, n_inputs: Optional[int] = None,
                 expm_squarings: int = 24, jitter: float = 0.0, nan_missing: bool = False):
        if (f is None) == (model is None):
            checks.fail(self, "give exactly one of f (a discrete map) and model (a continuous plant, with dt), "
                        f"got {'both' if f is not None else 'neither'}")
        if model is not None and dt is None:
            checks.fail(self, "dt must be given with a continuous model (the sample period), got None")
        if (h is None) == (C is None):
            checks.fail(self, "give exactly one of C (linear output) and h (nonlinear output), "
                        f"got {'both' if h is not None else 'neither'}")
        for name, v in (("Q", Q), ("R", R), ("P0", P0), ("xhat0", xhat0), ("C", C)):
            if v is not None:
                checks.check_real(self, name, v)
        checks.check_square(self, "P0", P0)
        self.Q, self.P0 = Q, P0
        self.xhat0 = jnp.zeros(jnp.shape(P0)[0]) if xhat0 is None else xhat0
        self.C = None if C is None else jnp.asarray(C, jnp.result_type(float))
        if C is not None:
            checks.check_ndim(self, "C", C, (2,), "a (p, n) output matrix")
        self.R = as_covariance(R, lambda: output_size(C, h, self.xhat0))
        self.nan_missing = nan_missing
        self.model, self.f, self.h, self.dt = model, f, h, dt
        self.n_inputs = (model.m if model is not None else 1) if n_inputs is None else n_inputs
        self.expm_squarings, self.jitter = expm_squarings, jitter

    def __check_init__(self):
        d = self.P0.shape[0]
        why = f"for a {d}-state model (P0 is {checks.fmt_shape(self.P0.shape)})"
        checks.check_covariance(self, "Q", self.Q, d, why)
        checks.check_covariance(self, "P0", self.P0, d)
        checks.check_state_vector(self, "xhat0", self.xhat0, d, why)
        if self.C is not None:
            checks.check_shape(self, "C", self.C, (None, d), why)
            checks.check_finite(self, "C", self.C)
            p = self.C.shape[0]
            checks.check_covariance(self, "R", self.R, p, f"for {p} measurements (C is {checks.fmt_shape(self.C.shape)})")
        else:
            checks.check_square(self, "R", self.R)
            checks.check_psd(self, "R", self.R)
        if self.model is not None:
            if not isinstance(self.model, Plant):
                raise checks.ArgumentTypeError(f"ExtendedKalmanFilter: model must be a jaxdip Plant, "
                                               f"got {type(self.model).__name__}")
            if self.model.n != d:
                checks.fail(self, f"model must have {d} states like P0, got {type(self.model).__name__} "
                            f"with {self.model.n}")
            checks.check_positive(self, "dt", self.dt)
        checks.check_int(self, "n_inputs", self.n_inputs, 0)
        checks.check_int(self, "expm_squarings", self.expm_squarings, 0)
        checks.check_nonnegative(self, "jitter", self.jitter)

    def io_sizes(self) -> dict:
        sizes = {"out": (self.P0.shape[0], f"P0 is {checks.fmt_shape(self.P0.shape)}"),
                 "u": (self.n_inputs, f"n_inputs={self.n_inputs}")}
        if self.C is not None:
            sizes["in"] = (self.C.shape[0], f"C is {checks.fmt_shape(self.C.shape)}")
        else:
            sizes["in"] = (self.R.shape[0], f"R is {checks.fmt_shape(self.R.shape)}")
        return sizes

    def _transition(self, x, u, j):
        if self.model is None:
            return jax.jacfwd(self.f, argnums=0)(x, u), self.f(x, u)
        lm = local_model(rhs, self.model, x, u, self.dt, with_inverse=False,
                         max_squarings=self.expm_squarings)
        return lm.Phi, lm.Phi @ x + (lm.W @ u + lm.b)

    def _output(self, x, k):
        if self.h is None:
            return self.C, self.C @ x
        return jax.jacfwd(self.h)(x), self.h(x)
