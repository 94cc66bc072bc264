"""The analysis of one ensemble Kalman update, per variant: perturbed-observation EKI, the ensemble-transform ETKI
and the unscented UKI. Each is a ``Variant``: ``init(start, key) -> aux`` (the variant's own state beside the
points), ``points(aux) -> (J, p)`` (where the forward map is evaluated next) and
``analysis(points, Y, ok, y, R, dt, key, localise, weighted, aux) -> (new points, aux, finite)``, ``finite``
telling whether the update can be applied (checked on the gain, the one quantity a bad ensemble makes infinite,
so that the thesis's update compiles to the same program, and gives the same numbers, as before the check). ``make_step`` (in
``jaxdip.search.steps``) composes a variant with a schedule, a localiser, a failure policy and an accelerator.

* ``eki()``: v_j <- v_j + C_vy (C_yy + R / dt)^-1 (y + dt^-1/2 xi_j - Y_j), xi_j ~ N(0, R) (the thesis's (2.22)
  with the Kalman sign at dt = 1);
* ``etki()``: the deterministic square-root update of Huang et al. (2022): with X, Z the ensemble's centred
  parameters and outputs over sqrt(J - 1), Omega = (I + dt Z R^-1 Z^T)^-1 (J x J) and
  v <- mean + (dt Omega Z R^-1 (y - mean Y) + sqrt(J - 1) Omega^1/2)^T X: the cost grows with J, not with the
  number of outputs, and no observation noise is drawn;
* ``uki()``: the unscented Kalman inversion (Huang, Schneider & Stuart 2022) with a Gaussian N(m, C) as its
  state and 2p + 1 sigma points m, m +- c sqrt(C)_i, c^2 = min(p, 4), the output mean taken at the centre
  (the modified unscented transform). Prediction C^ = (1 + dt) C (EnsembleKalmanProcesses.jl's ``Unscented``
  with alpha_reg = 1 and the evolution covariance updated to the current C), analysis with the output noise
  (1 + 1/dt) R (2R at dt = 1). On a linear map G its fixed point is the Gaussian with precision G^T R^-1 G about
  the least-squares solution; with a Gaussian prior appended to the outputs (``jaxdip.search.problems.tikhonov``)
  it is the posterior, mean and covariance.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from jaxdip._public import public_dir

__all__ = ["Variant", "eki", "etki", "uki", "ensemble_update", "unscented_points"]
__dir__ = public_dir(globals())


class Variant(NamedTuple):
    name: str
    init: Callable  # (start, key) -> aux
    points: Callable  # (aux, members) -> (J, p)
    analysis: Callable  # (V, Y, ok, y, R, dt, key, localise, weighted, aux) -> (V_new, aux, finite)
    ensemble: bool = True  # False: the points are not an ensemble to resample or accelerate (UKI)


def _scaled(x, s):
    # the thesis's step (dt = 1, a Python float) skips the multiplication, so its numbers stay bit-identical
    return x if isinstance(s, float) and s == 1.0 else x * s


def _moments(V, Y, ok, weighted):
    """Centred parameters and outputs (rows of failed members zero when ``weighted``) and the count."""
    if not weighted:
        return V - V.mean(axis=0), Y - Y.mean(axis=0), V.shape[0]
    w = ok.astype(V.dtype)
    vbar = (w[:, None] * V).sum(0) / w.sum()
    ybar = (w[:, None] * Y).sum(0) / w.sum()
    return (V - vbar) * w[:, None], (Y - ybar) * w[:, None], jnp.maximum(w.sum(), 2.0)


def _gain_update(V, Y, Yhat, R, dV, dY, n, localise):
    Cvy = dV.T @ dY / (n - 1)
    Cyy = dY.T @ dY / (n - 1)
    if localise is not None:
        Cvy, Cyy = localise(Cvy, Cyy, jnp.sum(dV * dV, axis=0) / (n - 1), n)
    gain_T = jnp.linalg.solve(Cyy + R, Cvy.T)  # (C_yy + R) is SPD: solve rather than invert
    return V + (Yhat - Y) @ gain_T, jnp.all(jnp.isfinite(gain_T))


def ensemble_update(V, Y, Yhat, R, W):
    """(2.22) with the Kalman sign, for given perturbed objectives Yhat (J, m) and perturbations W (J, p)."""
    dV, dY, n = _moments(V, Y, None, False)
    return _gain_update(V, Y, Yhat, R, dV, dY, n, None)[0] + W


def eki() -> Variant:
    """Perturbed-observation ensemble Kalman inversion."""

    def analysis(V, Y, ok, y, R, dt, key, localise, weighted, aux):
        J, m = Y.shape
        Yhat = y + _scaled(jax.random.normal(key, (J, m)) @ jnp.linalg.cholesky(R).T, _inv_sqrt(dt))
        dV, dY, n = _moments(V, Y, ok, weighted)
        new, finite = _gain_update(V, Y, Yhat, _scaled(R, _inv(dt)), dV, dY, n, localise)
        return new, aux, finite & jnp.all(jnp.isfinite(Yhat))

    return Variant("eki", lambda start, key: {}, lambda aux, members: members, analysis)


def _inv(dt):
    return 1.0 / dt if not isinstance(dt, float) or dt != 1.0 else 1.0


def _inv_sqrt(dt):
    return 1.0 / jnp.sqrt(dt) if not isinstance(dt, float) or dt != 1.0 else 1.0


def _sym_funcs(A):
    """A^-1 and A^-1/2 of a symmetric positive definite matrix, from one eigendecomposition."""
    lam, Q = jnp.linalg.eigh(A)
    return (Q / lam) @ Q.T, (Q / jnp.sqrt(lam)) @ Q.T


def etki() -> Variant:
    """Ensemble-transform Kalman inversion (deterministic square-root update)."""

    def analysis(V, Y, ok, y, R, dt, key, localise, weighted, aux):
        dV, dY, n = _moments(V, Y, ok, True)  # always weighted: with every member ok it is the plain mean
        X, Z = dV / jnp.sqrt(n - 1), dY / jnp.sqrt(n - 1)
        RiZ = jnp.linalg.solve(R, Z.T) * dt  # (m, J): (R / dt)^-1 Z^T
        Omega, root = _sym_funcs(jnp.eye(V.shape[0]) + Z @ RiZ)
        w = ok.astype(V.dtype)
        mean = (w[:, None] * V).sum(0) / w.sum()
        ybar = (w[:, None] * Y).sum(0) / w.sum()
        shift = Omega @ (RiZ.T @ (y - ybar))  # (J,)
        new = mean + (shift[None, :] + jnp.sqrt(n - 1) * root) @ X
        return new, aux, jnp.all(jnp.isfinite(new))

    return Variant("etki", lambda start, key: {}, lambda aux, members: members, analysis)


def unscented_points(mean, cov):
    """(2p + 1, p): the centre, then mean + c L_i and mean - c L_i (L L^T = cov), c^2 = min(p, 4).

    L is the symmetric square root with negative eigenvalues (rounding, or a covariance estimated from fewer
    members than parameters) clipped to zero, so a semidefinite covariance still has its points."""
    p = mean.shape[0]
    c = jnp.sqrt(min(p, 4.0))
    lam, Q = jnp.linalg.eigh(0.5 * (cov + cov.T))
    L = (Q * jnp.sqrt(jnp.maximum(lam, 0.0))) @ Q.T
    return jnp.concatenate([mean[None], mean + c * L.T, mean - c * L.T])


def uki() -> Variant:
    """Unscented Kalman inversion; its aux holds the Gaussian ``mean``, ``cov`` and the predicted ``cov_pred``."""

    def init(start, key):
        if isinstance(start, tuple):
            mean, cov = (jnp.asarray(a) for a in start)
        else:
            mean = start.mean(axis=0)
            d = start - mean
            cov = d.T @ d / (start.shape[0] - 1)
        return {"mean": mean, "cov": cov, "cov_pred": 2.0 * cov}

    def points(aux, members):
        return unscented_points(aux["mean"], aux["cov_pred"])

    def analysis(V, Y, ok, y, R, dt, key, localise, weighted, aux):
        p = V.shape[1]
        wc = 1.0 / (2.0 * min(p, 4.0))
        dV, dY = V[1:] - V[0], Y[1:] - Y[0]
        Cvy = wc * dV.T @ dY
        Cyy = wc * dY.T @ dY
        S = Cyy + (1.0 + 1.0 / dt) * R
        gain_T = jnp.linalg.solve(S, Cvy.T)  # (m, p)
        mean = V[0] + (y - Y[0]) @ gain_T
        cov = aux["cov_pred"] - Cvy @ gain_T
        cov = 0.5 * (cov + cov.T)
        new = {"mean": mean, "cov": cov, "cov_pred": (1.0 + dt) * cov}
        points = unscented_points(mean, new["cov_pred"])
        return points, new, jnp.all(jnp.isfinite(points)) & jnp.all(jnp.isfinite(cov))

    return Variant("uki", init, points, analysis, ensemble=False)
