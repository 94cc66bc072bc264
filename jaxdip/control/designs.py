"""LQR regulators and Kalman estimator gains (python-control's ``lqr``, ``dlqr``, ``lqe``, ``dlqe`` and integral
action), built on the Riccati solvers of ``jaxdip.control.riccati`` and differentiable through their implicit
JVPs.

Conventions are python-control 0.10's: ``K, S, E = lqr(A, B, Q, R, N)`` with u = -K x, S the Riccati solution
and E the closed-loop eigenvalues; ``L, P, E = lqe(A, G, C, QN, RN)``. A cross weight N (the cost term
2 x^T N u) is removed by the usual change of variables, A - B R^-1 N^T and Q - N R^-1 N^T, so the solvers see a
problem without one; the joint weight [[Q, N], [N^T, R]] must be positive semidefinite (python-control does not
check this; jaxdip raises an ``ArgumentError``).

Errors. Concrete inputs without a stabilising solution raise ``RiccatiError`` (a ``numpy.linalg.LinAlgError``,
the class python-control raises); traced calls (jit, vmap, grad) are not checked: read a result code with
``riccati_status`` on the returned Riccati solution (for ``lqe``: ``riccati_status(A.T, C.T, G QN G^T, RN, P)``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.control._riccati_args import check_problem
from jaxdip.control.riccati import RTOL, _care, _dare, _f64, _hewer, _host_check, _RNotPositiveDefinite
from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["lqr", "dlqr", "lqi", "lqe", "dlqe"]
__dir__ = public_dir(globals())

_POLISH = 2  # Newton-Hewer steps after the doubling, for a DARE with a cross weight


def _cross(owner: str, Q, R, N, n: int, m: int):
    """N as an (n, m) float64 matrix, with the joint weight checked PSD on the host."""
    checks.check_real(owner, "N", N)
    N = jnp.atleast_2d(jnp.asarray(N, dtype=jnp.float64))
    checks.check_shape(owner, "N", N, (n, m), f"for {n} states and {m} inputs")
    checks.check_finite(owner, "N", N)
    if checks.is_concrete(Q, R, N):
        J = np.block([[np.asarray(Q), np.asarray(N)], [np.asarray(N).T, np.asarray(R)]])
        try:
            checks.check_psd(owner, "[[Q, N], [N^T, R]]", J)
        except checks.ArgumentError as e:
            raise checks.ArgumentError(f"{e} (the cross weight N makes the cost indefinite)") from None
    return N


def _reduce(A, B, Q, R, N):
    """The problem without a cross term: (A - B R^-1 N^T, Q - N R^-1 N^T)."""
    RiNt = jnp.linalg.solve(R, N.T)
    Qr = Q - N @ RiNt
    return A - B @ RiNt, 0.5 * (Qr + Qr.T)


def _solve(owner, A, B, Q, R, N, discrete: bool, rtol: float, values: bool = True):
    check_problem(owner, A, B, Q, R, _RNotPositiveDefinite, values=values)
    A, B, Q, R = _f64(A, B, Q, R)
    n, m = B.shape
    cross = N is not None
    if N is None:  # no reduction: the same operations (and numbers) as without a cross weight
        N, Ar, Qr = jnp.zeros((n, m)), A, Q
    else:
        N = _cross(owner, Q, R, N, n, m)
        Ar, Qr = _reduce(A, B, Q, R, N)
    if discrete:
        S = _dare(Ar, B, Qr, R, 40)
        if cross:
            # the reduced A - B R^-1 N^T can be far more unstable than A, and the doubling loses digits on it
            # (1e-8 relative where the problem's conditioning allows 1e-12): Newton-Hewer steps restore them
            S = _hewer(Ar, B, Qr, R, S, _POLISH)
        _host_check(Ar, B, Qr, R, S, True, rtol, "raise iters")
        K = jnp.linalg.solve(R + B.T @ S @ B, B.T @ S @ A + N.T)
    else:
        S = _care(Ar, B, Qr, R, 60, 3)
        _host_check(Ar, B, Qr, R, S, False, rtol, "raise sign_iters or newton_iters")
        K = jnp.linalg.solve(R, B.T @ S + N.T)
    return K, S, jnp.linalg.eigvals(A - B @ K)


def lqr(A, B, Q, R, N=None, *, rtol: float = RTOL) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Continuous LQR: (K, S, E) minimising the integral of x^T Q x + u^T R u + 2 x^T N u, with u = -K x.

    S solves A^T S + S A - (S B + N) R^-1 (B^T S + N^T) + Q = 0, E = eig(A - B K). Raises ``RiccatiError`` for
    concrete inputs without a stabilising solution, like python-control's ``lqr``; under jit use
    ``riccati_status`` on S for a result code (with N: on the reduced problem, see the module notes)."""
    return _solve("lqr", A, B, Q, R, N, False, rtol)


def dlqr(A, B, Q, R, N=None, *, rtol: float = RTOL) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Discrete LQR: (K, S, E) minimising the sum of x^T Q x + u^T R u + 2 x^T N u, with u_k = -K x_k
    (K = (R + B^T S B)^-1 (B^T S A + N^T)); raises like ``lqr``."""
    return _solve("dlqr", A, B, Q, R, N, True, rtol)


def lqi(A, B, C, Q, R, N=None, *, dt: float = 0.0,
        rtol: float = RTOL) -> tuple[jax.Array, jax.Array, jax.Array]:
    """LQR with integral action on z = C x: python-control's ``lqr(A, B, Q, R, N, integral_action=C)`` (or
    ``dlqr`` for ``dt`` > 0).

    The state is augmented with the integrals xi' = C x (continuous) or xi_{k+1} = xi_k + C x_k (discrete), so
    Q and N are over (x, xi): Q is (n + p, n + p) and K is (m, n + p), u = -K [x; xi]. MATLAB's ``lqi``
    integrates r - y instead, which flips the sign of the integral gains."""
    A, B = _f64(A, B)
    C = jnp.atleast_2d(jnp.asarray(C, dtype=jnp.float64))
    n, m = B.shape
    checks.check_shape("lqi", "C", C, (C.shape[0], n), f"for a {n}-state model")
    p = C.shape[0]
    corner = jnp.eye(p) if dt else jnp.zeros((p, p))
    Aa = jnp.block([[A, jnp.zeros((n, p))], [C, corner]])
    Ba = jnp.concatenate([B, jnp.zeros((p, m))], axis=0)
    return _solve("lqi", Aa, Ba, Q, R, N, bool(dt), rtol)


def _estimator(owner, A, G, C, QN, RN, discrete: bool, rtol: float):
    A, G, C = _f64(A, G, C)
    n = A.shape[0]
    checks.check_shape(owner, "C", C, (C.shape[0], n), f"for a {n}-state model")
    checks.check_shape(owner, "G", G, (n, G.shape[1]), f"for a {n}-state model")
    QN, RN = _f64(QN, RN)
    checks.check_shape(owner, "QN", QN, (G.shape[1], G.shape[1]), f"for {G.shape[1]} noise inputs (G's columns)")
    checks.check_shape(owner, "RN", RN, (C.shape[0], C.shape[0]), f"for {C.shape[0]} outputs (C's rows)")
    # the noise covariances are checked, not G QN G^T: its zero eigenvalues come out of rounding as -1e-8 relative
    # when G is badly scaled
    checks.check_psd(owner, "QN", QN)
    try:
        checks.check_psd(owner, "RN", RN, definite=True)
    except checks.ArgumentError as e:
        raise _RNotPositiveDefinite(f"{e}: RN is not positive definite") from None
    GQG = G @ QN @ G.T
    K, P, E = _solve(owner, A.T, C.T, 0.5 * (GQG + GQG.T), RN, None, discrete, rtol, values=False)
    return K.T, P, E


def lqe(A, G, C, QN, RN, *, rtol: float = RTOL) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Kalman-Bucy gain of x' = A x + B u + G w, y = C x + v (cov w = QN, cov v = RN): (L, P, E) with
    L = P C^T RN^-1, P the steady error covariance and E = eig(A - L C), as python-control's ``lqe`` (which
    also has no cross-covariance NN). Raises ``RiccatiError`` like ``lqr``."""
    return _estimator("lqe", A, G, C, QN, RN, False, rtol)


def dlqe(A, G, C, QN, RN, *, rtol: float = RTOL) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Discrete steady Kalman gain, python-control's ``dlqe``: (L, P, E) with P the predicted covariance
    (P = A P A^T - A P C^T (C P C^T + RN)^-1 C P A^T + G QN G^T), L = A P C^T (C P C^T + RN)^-1 the gain of
    the predictor x^_{k+1} = A x^_k + B u_k + L (y_k - C x^_k), and E = eig(A - L C)."""
    return _estimator("dlqe", A, G, C, QN, RN, True, rtol)
