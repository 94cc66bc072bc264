"""Riccati equations in pure JAX (the LQR and estimator designs built on them are in ``jaxdip.control.designs``).

* CARE: the matrix sign function of the Hamiltonian (scaled Newton iteration) gives the stable invariant
  subspace, and Newton-Kleinman steps (a Lyapunov solve each, by Kronecker products: n is at most ~6
  here) polish the solution to machine precision.
* DARE: the structure-preserving doubling algorithm, quadratically convergent for stabilisable/detectable
  pairs.

Both carry custom JVPs by implicit differentiation of the Riccati equation (one Lyapunov/Stein solve per
tangent), so gradients of a closed loop reach the model and the weights without unrolling the iterations.

Failure reporting. The solvers run fixed iteration counts (so they jit, vmap and differentiate), and a fixed
count cannot itself tell whether it converged, so convergence is judged on the answer:

* converged: X is finite and the relative Riccati residual (the residual's Frobenius norm over the sum of
  the norms of the equation's terms) is at most ``rtol`` (default 1e-8: backward-stable solvers reach ~1e-15,
  an unconverged iteration is off by far more);
* stabilising: the closed loop A - B K is strictly stable (max Re < 0, or spectral radius < 1).

Symmetry is not checked (both solvers symmetrise their iterates, so it cannot fail), nor is X >= 0: a stable
closed loop with a zero residual makes X the unique stabilising solution, the integral of
e^(Acl^T t) (Q + K^T R K) e^(Acl t), which is PSD whenever Q is.

``care_checked`` / ``dare_checked`` / ``riccati_status`` return a ``RiccatiCode`` next to X and never raise, so
they work under jit, vmap and grad; ``error_if_failed`` turns a code into an equinox runtime error for whoever
opts in. ``care``, ``dare``, ``lqr`` and ``dlqr`` called with concrete arrays check the answer on the host and
raise ``RiccatiError`` (a ``numpy.linalg.LinAlgError``, the class python-control raises) naming the cause,
found by PBH rank tests: (A, B) not stabilisable, an unobservable mode of (Q, A) on the stability boundary
(then no stabilising solution exists), R not positive definite, or plain non-convergence. Traced calls (inside
jit, vmap, grad) are never checked, so an experiment inside jit does not stop on a check.

Against python-control on the same inputs (tests/test_lqr.py): both raise for a non-stabilisable pair; both
return the stabilising solution when (Q, A) is not detectable but its unobservable modes are off the boundary
(for the DARE the doubling algorithm diverges there, so ``dare`` falls back to a regularised doubling run
polished by Newton-Hewer steps, only when the doubling result is not finite); where an unobservable mode sits
on the boundary python-control (SciPy's Schur solver) returns a marginally stable gain and jaxdip raises,
because no stabilising solution exists.
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.control._riccati_args import check_problem
from jaxdip.control.lyapunov import _dlyap, _lyap
from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["RTOL", "RiccatiError", "RiccatiCode", "care", "care_checked", "dare", "dare_checked", "riccati_status",
           "error_if_failed"]
__dir__ = public_dir(globals())

RTOL = 1e-8  # relative Riccati residual below which a solution counts as converged
_PBH_TOL = 1e-6  # relative tolerances of the diagnostic PBH tests (they only name a failure already found)
_REG = 1e-6  # relative weight of the identity added to Q in the DARE fallback
_HEWER_STEPS = 3  # Newton-Hewer steps after the regularised doubling: from O(_REG) to rounding level


class RiccatiError(np.linalg.LinAlgError):
    """The Riccati equation has no stabilising solution, or the solver did not reach it."""


class RiccatiCode:
    """Result codes of ``care_checked`` / ``dare_checked`` / ``riccati_status`` (int32 arrays)."""

    OK = 0
    NOT_CONVERGED = 1  # X not finite, or relative residual above rtol
    NOT_STABILISING = 2  # residual small but A - B K not strictly stable

    messages = ("ok", "not converged (non-finite X or Riccati residual above tolerance)",
                "not stabilising (closed loop not strictly stable)")

    @classmethod
    def describe(cls, code) -> str:
        return cls.messages[int(code)]


class _RNotPositiveDefinite(RiccatiError, checks.ArgumentError):
    """R not positive definite: an argument error, raised as the ``RiccatiError`` python-control users expect."""


def _f64(*arrs):
    return [jnp.atleast_2d(jnp.asarray(a, dtype=jnp.float64)) for a in arrs]


def care(A, B, Q, R, sign_iters: int = 60, newton_iters: int = 3, *, rtol: float = RTOL) -> jax.Array:
    """Stabilising solution X of A^T X + X A - X B R^-1 B^T X + Q = 0 (differentiable in A, B, Q, R).

    With concrete inputs a failed solve raises ``RiccatiError``; traced calls are not checked (see
    ``care_checked``)."""
    check_problem("care", A, B, Q, R, _RNotPositiveDefinite)
    A, B, Q, R = _f64(A, B, Q, R)
    X = _care(A, B, Q, R, sign_iters, newton_iters)
    _host_check(A, B, Q, R, X, False, rtol, "raise sign_iters or newton_iters")
    return X


def care_checked(A, B, Q, R, sign_iters: int = 60, newton_iters: int = 3, *,
                 rtol: float = RTOL) -> tuple[jax.Array, jax.Array]:
    """``(X, code)``: the CARE solution and its ``RiccatiCode``; never raises, so it works under jit/vmap/grad."""
    check_problem("care_checked", A, B, Q, R, _RNotPositiveDefinite, values=False)
    A, B, Q, R = _f64(A, B, Q, R)
    X = _care(A, B, Q, R, sign_iters, newton_iters)
    return X, riccati_status(A, B, Q, R, X, discrete=False, rtol=rtol)


@partial(jax.custom_jvp, nondiff_argnums=(4, 5))
def _care(A, B, Q, R, sign_iters, newton_iters):
    return _care_solve(A, B, Q, R, sign_iters, newton_iters)


# jitted once per shape: an eager fori_loop compiles its body anew at every call (experiments solve many
# Riccati equations while they set up, and each eager solve cost ~0.5 s of compilation)
@partial(jax.jit, static_argnums=(4, 5))
def _care_solve(A, B, Q, R, sign_iters, newton_iters):
    n = A.shape[0]
    G = B @ jnp.linalg.solve(R, B.T)
    H = jnp.block([[A, -G], [-Q, -A.T]])

    def sign_step(_, Z):
        # determinant scaling speeds up the first iterations; slogdet keeps it finite for any size
        _, logdet = jnp.linalg.slogdet(Z)
        c = jnp.exp(-logdet / (2 * n))
        return 0.5 * (c * Z + jnp.linalg.inv(Z) / c)

    Z = jax.lax.fori_loop(0, sign_iters, sign_step, H)
    I = jnp.eye(n)
    lhs = jnp.concatenate([Z[:n, n:], Z[n:, n:] + I], axis=0)
    rhs = -jnp.concatenate([Z[:n, :n] + I, Z[n:, :n]], axis=0)
    X = jnp.linalg.lstsq(lhs, rhs)[0]
    X = 0.5 * (X + X.T)

    def newton(_, X):
        K = jnp.linalg.solve(R, B.T @ X)
        Acl = A - B @ K
        return _lyap(Acl.T, Q + K.T @ R @ K)

    return jax.lax.fori_loop(0, newton_iters, newton, X)


@_care.defjvp
def _care_jvp(sign_iters, newton_iters, primals, tangents):
    # Implicit differentiation. At the solution, with K = R^-1 B^T X and Acl = A - B K, the CARE reads
    # Acl^T X + X Acl + Q + K^T R K = 0 and is stationary in K, so K may be held fixed:
    # Acl^T dX + dX Acl = -(dQ + K^T dR K + dAcl^T X + X dAcl), dAcl = dA - dB K.
    A, B, Q, R = primals
    dA, dB, dQ, dR = tangents
    X = _care(A, B, Q, R, sign_iters, newton_iters)
    K = jnp.linalg.solve(R, B.T @ X)
    Acl = A - B @ K
    dAcl = dA - dB @ K
    rhs = dQ + K.T @ dR @ K + dAcl.T @ X + X @ dAcl
    return X, _lyap(Acl.T, 0.5 * (rhs + rhs.T))


def dare(A, B, Q, R, iters: int = 40, *, rtol: float = RTOL) -> jax.Array:
    """Stabilising solution X of X = A^T X A - A^T X B (R + B^T X B)^-1 B^T X A + Q (doubling algorithm;
    differentiable in A, B, Q, R). With concrete inputs a failed solve raises ``RiccatiError``."""
    check_problem("dare", A, B, Q, R, _RNotPositiveDefinite)
    A, B, Q, R = _f64(A, B, Q, R)
    X = _dare(A, B, Q, R, iters)
    _host_check(A, B, Q, R, X, True, rtol, "raise iters")
    return X


def dare_checked(A, B, Q, R, iters: int = 40, *, rtol: float = RTOL) -> tuple[jax.Array, jax.Array]:
    """``(X, code)``: the DARE solution and its ``RiccatiCode``; never raises, so it works under jit/vmap/grad."""
    check_problem("dare_checked", A, B, Q, R, _RNotPositiveDefinite, values=False)
    A, B, Q, R = _f64(A, B, Q, R)
    X = _dare(A, B, Q, R, iters)
    return X, riccati_status(A, B, Q, R, X, discrete=True, rtol=rtol)


@partial(jax.jit, static_argnums=3)
def _sda(A, G, Q, iters):
    I = jnp.eye(A.shape[0])

    def sda(_, s):
        Ak, Gk, Hk = s
        W = I + Gk @ Hk
        WA = jnp.linalg.solve(W, Ak)
        WG = jnp.linalg.solve(W, Gk)
        A1 = Ak @ WA
        G1 = Gk + Ak @ WG @ Ak.T
        H1 = Hk + Ak.T @ Hk @ WA
        return A1, 0.5 * (G1 + G1.T), 0.5 * (H1 + H1.T)

    _, _, X = jax.lax.fori_loop(0, iters, sda, (A, G, Q))
    return X


@partial(jax.jit, static_argnums=5)
def _dare_regularised(A, B, Q, R, G, iters):
    # The doubling needs (Q, A) detectable as well: its dual iterate G_k diverges on an unobservable mode
    # outside the unit circle, although the stabilising X exists. Q + eps I is detectable, its stabilising
    # solution is within O(eps) of the one wanted (which is analytic in Q while it exists), and Newton-Hewer
    # steps from that stabilising gain converge quadratically to the solution for Q itself.
    n = A.shape[0]
    # eps in Q's units: ||R|| / ||B||^2 is a weight per squared state as well
    scale = jnp.linalg.norm(Q) + jnp.linalg.norm(R) / jnp.maximum(jnp.linalg.norm(B) ** 2, jnp.finfo(A.dtype).tiny)
    X = _sda(A, G, Q + _REG * scale * jnp.eye(n), iters)

    return _hewer(A, B, Q, R, X, _HEWER_STEPS)


def _hewer(A, B, Q, R, X, steps: int):
    """``steps`` Newton-Hewer steps on the DARE from a stabilising X (each one Stein solve; quadratic)."""

    def hewer(_, X):
        K = jnp.linalg.solve(R + B.T @ X @ B, B.T @ X @ A)
        Acl = A - B @ K
        return _dlyap(Acl.T, Q + K.T @ R @ K)

    return jax.lax.fori_loop(0, steps, hewer, X)


@partial(jax.custom_jvp, nondiff_argnums=(4,))
def _dare(A, B, Q, R, iters):
    G = B @ jnp.linalg.solve(R, B.T)
    X = _sda(A, G, Q, iters)
    # the fallback only replaces a non-finite doubling result, so well-posed problems keep their numbers
    if not isinstance(X, jax.core.Tracer):  # an eager call decides in Python and compiles one branch, not both
        return X if bool(jnp.all(jnp.isfinite(X))) else _dare_regularised(A, B, Q, R, G, iters)
    return jax.lax.cond(jnp.all(jnp.isfinite(X)), lambda: X, lambda: _dare_regularised(A, B, Q, R, G, iters))


@_dare.defjvp
def _dare_jvp(iters, primals, tangents):
    # Implicit differentiation of X = Q + K^T R K + Acl^T X Acl (stationary in the optimal K):
    # dX - Acl^T dX Acl = dQ + K^T dR K + dAcl^T X Acl + Acl^T X dAcl, dAcl = dA - dB K.
    A, B, Q, R = primals
    dA, dB, dQ, dR = tangents
    X = _dare(A, B, Q, R, iters)
    K = jnp.linalg.solve(R + B.T @ X @ B, B.T @ X @ A)
    Acl = A - B @ K
    dAcl = dA - dB @ K
    rhs = dQ + K.T @ dR @ K + dAcl.T @ X @ Acl + Acl.T @ X @ dAcl
    return X, _dlyap(Acl.T, 0.5 * (rhs + rhs.T))


# ---- checks --------------------------------------------------------------------------------------------------


def _stats(A, B, Q, R, X, discrete: bool):
    """(relative residual, stability margin) of a candidate X; margin < 0 means a strictly stable closed loop."""
    A, B, Q, R, X = (jax.lax.stop_gradient(v) for v in (A, B, Q, R, X))
    nrm = jnp.linalg.norm
    if discrete:
        XB = X @ B
        K = jnp.linalg.solve(R + B.T @ XB, XB.T @ A)
        AXA = A.T @ X @ A
        T = A.T @ XB @ K  # A^T X B (R + B^T X B)^-1 B^T X A
        res = AXA - X - T + Q
        scale = nrm(AXA) + nrm(X) + nrm(T) + nrm(Q)
        margin = jnp.max(jnp.abs(jnp.linalg.eigvals(A - B @ K))) - 1.0
    else:
        K = jnp.linalg.solve(R, B.T @ X)
        XA = X @ A
        T = X @ B @ K  # X B R^-1 B^T X
        res = XA.T + XA - T + Q
        scale = 2 * nrm(XA) + nrm(T) + nrm(Q)
        margin = jnp.max(jnp.real(jnp.linalg.eigvals(A - B @ K)))
    # scale = 0 only for X = 0 and Q = 0, a solution iff res = 0
    rel = jnp.where(scale > 0, nrm(res) / jnp.where(scale > 0, scale, 1.0), nrm(res))
    rel = jnp.where(jnp.all(jnp.isfinite(X)), rel, jnp.inf)
    return rel, margin


def _code(rel, margin, rtol):
    return jnp.where(rel <= rtol, jnp.where(margin < 0, RiccatiCode.OK, RiccatiCode.NOT_STABILISING),
                     RiccatiCode.NOT_CONVERGED).astype(jnp.int32)


def riccati_status(A, B, Q, R, X, *, discrete: bool = False, rtol: float = RTOL) -> jax.Array:
    """``RiccatiCode`` of a candidate solution X of the CARE (or, with ``discrete``, the DARE); jit/vmap-safe.
    E.g. ``riccati_status(A, B, Q, R, lqr(A, B, Q, R)[1])`` inside jit."""
    A, B, Q, R, X = _f64(A, B, Q, R, X)
    return _code(*_stats(A, B, Q, R, X, discrete), rtol)


def error_if_failed(X, code):
    """Opt-in: X, with an equinox runtime error (``EQX_ON_ERROR`` decides how it surfaces) when code is not OK.
    Works inside jit and vmap; the checked solvers themselves never raise there."""
    return eqx.branched_error_if(X, code != RiccatiCode.OK, code, RiccatiCode.messages)


_stats_jit = jax.jit(_stats, static_argnums=5)


def _host_check(A, B, Q, R, X, discrete: bool, rtol: float, hint: str) -> None:
    if isinstance(X, jax.core.Tracer):  # inside jit / vmap / grad: report nothing, raise nothing
        return
    rel, margin = (float(v) for v in _stats_jit(A, B, Q, R, X, discrete))
    code = int(_code(rel, margin, rtol))
    if code == RiccatiCode.OK:
        return
    eq = "DARE" if discrete else "CARE"
    cause = _diagnose(*(np.asarray(v) for v in (A, B, Q, R)), discrete)
    if code == RiccatiCode.NOT_CONVERGED:
        detail = (f"relative residual {rel:.2e} above {rtol:.0e}" if np.isfinite(rel) else "non-finite solution")
    else:
        detail = ("closed-loop spectral radius " + f"{margin + 1:.6g}" if discrete
                  else f"closed-loop max Re(eigenvalue) {margin:.6g}")
    if cause is None:
        what = "did not converge" if code == RiccatiCode.NOT_CONVERGED else "returned a non-stabilising solution"
        raise RiccatiError(f"cannot solve the {eq}: the solver {what} ({detail}; {hint})")
    raise RiccatiError(f"cannot solve the {eq}: {cause} ({detail})")


def _diagnose(A, B, Q, R, discrete: bool) -> str | None:
    """Name the structural reason a Riccati equation has no stabilising solution, or None if none is found."""
    w = np.linalg.eigvalsh(0.5 * (R + R.T))
    if w.min() <= 0:
        return f"R is not positive definite (smallest eigenvalue {w.min():.3g})"
    n = A.shape[0]
    lam = np.linalg.eigvals(A)
    a = max(1.0, np.linalg.norm(A, 2))
    if discrete:
        unstable, boundary = np.abs(lam) >= 1 - _PBH_TOL, np.abs(np.abs(lam) - 1) <= _PBH_TOL
        region = "|eigenvalue| >= 1"
        where = "on the unit circle"
    else:
        unstable, boundary = lam.real >= -_PBH_TOL * a, np.abs(lam.real) <= _PBH_TOL * a
        region = "Re(eigenvalue) >= 0"
        where = "on the imaginary axis"

    def normalised(M):
        s = np.linalg.norm(M, 2)
        return M / s if s > 0 else M

    def rank_deficient(lm, M, stack):
        # PBH test: rank [A - lm I, B] < n (controllability) or rank [A - lm I; C] < n (observability)
        L = A - lm * np.eye(n)
        sv = np.linalg.svd(stack([L, M]), compute_uv=False)
        return sv[n - 1] <= _PBH_TOL * (a + abs(lm))

    Bn = normalised(B)
    for lm in lam[unstable]:
        if rank_deficient(lm, Bn, lambda ms: np.hstack(ms)):
            return (f"(A, B) is not stabilisable: the mode {_fmt(lm)} of A ({region}) is not controllable "
                    f"from B, so no feedback gain moves it")
    wq, V = np.linalg.eigh(0.5 * (Q + Q.T))
    Qh = normalised((V * np.sqrt(np.clip(wq, 0, None))) @ V.T)
    for lm in lam[boundary]:
        if rank_deficient(lm, Qh, lambda ms: np.vstack(ms)):
            return (f"no stabilising solution: the mode {_fmt(lm)} of A {where} is unobservable from Q (the cost "
                    f"does not see it, so the optimal gain leaves it in place)")
    return None


def _fmt(lm) -> str:
    return f"{lm.real:.6g}" if abs(lm.imag) <= 1e-12 * max(1.0, abs(lm)) else f"{lm:.6g}"
