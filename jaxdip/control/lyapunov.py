"""Lyapunov and Sylvester equations, controllability/observability matrices and Gramians (python-control's
``lyap``, ``dlyap``, ``ctrb``, ``obsv``, ``gram``), in pure JAX: jit-able, vmap-able and differentiable.

The equations are solved in Kronecker form (one dense solve of size n^2, or n m for Sylvester): exact to
rounding and differentiable by JAX's rule for ``solve``, and cheap for the small n of pendulum models (n <= ~10;
a Bartels-Stewart solver would be O(n^3), but needs a Schur form JAX cannot differentiate in general).

Conventions are python-control's: ``lyap(A, Q)`` solves A X + X A^T + Q = 0, ``lyap(A, Q, C)`` the Sylvester
equation A X + X Q + C = 0, ``dlyap(A, Q)`` A X A^T - X + Q = 0 and ``dlyap(A, Q, C)`` A X Q^T - X + C = 0.

Errors. A singular equation (eigenvalues with lambda_i + mu_j = 0, or lambda_i mu_j = 1 in discrete time) has no
unique solution: with concrete arrays ``lyap``/``dlyap`` raise ``LyapunovError`` (a ``numpy.linalg.LinAlgError``)
where SciPy, behind python-control, returns an inaccurate matrix without a word. ``gram`` raises an
``ArgumentError`` (a ``ValueError``, as python-control's) for a system that is not strictly stable; traced calls are
not checked on the host, and ``gram`` returns a matrix of NaN for an unstable system under jit instead (its code).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.control.statespace import StateSpace
from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["LyapunovError", "lyap", "dlyap", "ctrb", "obsv", "gram"]
__dir__ = public_dir(globals())

_RTOL = 1e-8  # relative residual above which a host-path solve counts as singular
_SEP = 1e-10  # relative eigenvalue gap (lambda + mu, or 1 - lambda mu) below which the equation is singular


class LyapunovError(np.linalg.LinAlgError):
    """The Lyapunov/Sylvester equation is singular (no unique solution)."""


def _mat(owner: str, name: str, v, square: bool = False) -> jax.Array:
    checks.check_real(owner, name, v)
    shape = checks.shape_of(v)
    if len(shape) > 2:
        checks.fail(owner, f"{name} must be a matrix, got shape {checks.fmt_shape(shape)}")
    if square:
        shape2 = (1,) * (2 - len(shape)) + tuple(shape)
        if shape2[0] != shape2[1]:
            checks.fail(owner, f"{name} must be a square matrix, got shape {checks.fmt_shape(shape)}")
    checks.check_finite(owner, name, v)
    return jnp.atleast_2d(jnp.asarray(v, dtype=jnp.float64))


def _symmetric(owner: str, Q) -> None:
    if not checks.is_concrete(Q):
        return
    q = np.asarray(Q)
    if np.max(np.abs(q - q.T), initial=0.0) > 1e-6 * max(np.max(np.abs(q)), 1e-300):
        checks.fail(owner, "Q must be symmetric (for a non-symmetric right-hand side pass it as C: the Sylvester "
                           "form)")


def _expect(owner: str, name: str, M, shape: tuple, why: str) -> None:
    if tuple(M.shape) != shape:
        checks.fail(owner, f"{name} must be {checks.fmt_shape(shape)} {why}, got {checks.fmt_shape(M.shape)}")


def _kron_solve(L, rhs, shape):
    return jnp.linalg.solve(L, rhs.reshape(-1)).reshape(shape)


def _host_check(owner: str, X, residual, scale, A, Q, discrete: bool) -> None:
    """Raise on a singular equation: eigenvalues lambda of A and mu of Q (A itself in the Lyapunov form) with
    lambda + mu = 0 (or lambda mu = 1) to working precision, or a solve that did not satisfy the equation. A nearly
    singular Kronecker matrix still gives a small residual (the solve is backward stable), hence the eigenvalues."""
    if not checks.is_concrete(X, A, Q):
        return
    lam, mu = np.linalg.eigvals(np.asarray(A)), np.linalg.eigvals(np.asarray(Q))
    gap = np.abs(1 - lam[:, None] * mu[None, :]) if discrete else np.abs(lam[:, None] + mu[None, :])
    size = 1.0 if discrete else max(np.abs(lam).max(initial=0), np.abs(mu).max(initial=0), 1e-300)
    r, s = float(jnp.linalg.norm(residual)), max(float(scale), 1e-300)
    if gap.min() <= _SEP * size or not (np.all(np.isfinite(np.asarray(X))) and r <= _RTOL * s):
        raise LyapunovError(f"{owner}: the equation is singular (eigenvalues of its coefficients "
                            + ("multiply to one" if discrete else "sum to zero") + f": smallest gap {gap.min():.2e}),"
                            f" so it has no unique solution")


def lyap(A, Q, C=None) -> jax.Array:
    """X with A X + X A^T + Q = 0 (Q symmetric), or, given C, the Sylvester solution of A X + X Q + C = 0.

    python-control's ``lyap(A, Q, C)`` without its generalised ``E`` form. Raises ``LyapunovError`` on a singular
    equation (concrete inputs only)."""
    A = _mat("lyap", "A", A, square=True)
    n = A.shape[0]
    Q = _mat("lyap", "Q", Q, square=True)
    if C is None:
        _expect("lyap", "Q", Q, (n, n), f"for a {n}-state model (A is {checks.fmt_shape(A.shape)})")
        _symmetric("lyap", Q)
        X = _lyap(A, Q)
        _host_check("lyap", X, A @ X + X @ A.T + Q, 2 * jnp.linalg.norm(A @ X) + jnp.linalg.norm(Q), A, A, False)
        return X
    m = Q.shape[0]
    C = _mat("lyap", "C", C)
    _expect("lyap", "C", C, (n, m), f"(A is {checks.fmt_shape(A.shape)}, Q {checks.fmt_shape(Q.shape)})")
    X = _kron_solve(jnp.kron(A, jnp.eye(m)) + jnp.kron(jnp.eye(n), Q.T), -C, (n, m))
    _host_check("lyap", X, A @ X + X @ Q + C, jnp.linalg.norm(A @ X) + jnp.linalg.norm(X @ Q) + jnp.linalg.norm(C),
                A, Q, False)
    return X


def dlyap(A, Q, C=None) -> jax.Array:
    """X with A X A^T - X + Q = 0 (Q symmetric), or, given C, the solution of A X Q^T - X + C = 0 (python-control's
    ``dlyap`` without ``E``). Raises ``LyapunovError`` on a singular equation (concrete inputs only)."""
    A = _mat("dlyap", "A", A, square=True)
    n = A.shape[0]
    Q = _mat("dlyap", "Q", Q, square=True)
    if C is None:
        _expect("dlyap", "Q", Q, (n, n), f"for a {n}-state model (A is {checks.fmt_shape(A.shape)})")
        _symmetric("dlyap", Q)
        X = _dlyap(A, Q)
        _host_check("dlyap", X, A @ X @ A.T - X + Q, jnp.linalg.norm(A @ X @ A.T) + jnp.linalg.norm(X)
                    + jnp.linalg.norm(Q), A, A, True)
        return X
    m = Q.shape[0]
    C = _mat("dlyap", "C", C)
    _expect("dlyap", "C", C, (n, m), f"(A is {checks.fmt_shape(A.shape)}, Q {checks.fmt_shape(Q.shape)})")
    X = _kron_solve(jnp.eye(n * m) - jnp.kron(A, Q), C, (n, m))
    _host_check("dlyap", X, A @ X @ Q.T - X + C, jnp.linalg.norm(A @ X @ Q.T) + jnp.linalg.norm(X)
                + jnp.linalg.norm(C), A, Q, True)
    return X


def _lyap(A, Q):
    """A X + X A^T + Q = 0 without checks (the Riccati solvers' Newton steps call it with A^T)."""
    n = A.shape[0]
    I = jnp.eye(n, dtype=A.dtype)
    X = _kron_solve(jnp.kron(A, I) + jnp.kron(I, A), -Q, (n, n))
    return 0.5 * (X + X.T)


def _dlyap(A, Q):
    """A X A^T - X + Q = 0 without checks."""
    n = A.shape[0]
    X = _kron_solve(jnp.eye(n * n, dtype=A.dtype) - jnp.kron(A, A), Q, (n, n))
    return 0.5 * (X + X.T)


def ctrb(A, B, t: int | None = None) -> jax.Array:
    """Controllability matrix [B, A B, ..., A^(t-1) B] (t = n by default), as python-control's ``ctrb``."""
    A = _mat("ctrb", "A", A, square=True)
    B = _mat("ctrb", "B", B)
    n = A.shape[0]
    _expect("ctrb", "B", B, (n, B.shape[1]), f"for a {n}-state model")
    t = n if t is None else t
    checks.check_int("ctrb", "t", t, minimum=1)
    blocks = [B]
    for _ in range(t - 1):
        blocks.append(A @ blocks[-1])
    return jnp.concatenate(blocks, axis=1)


def obsv(A, C, t: int | None = None) -> jax.Array:
    """Observability matrix [C; C A; ...; C A^(t-1)] (t = n by default), as python-control's ``obsv``."""
    A = _mat("obsv", "A", A, square=True)
    C = _mat("obsv", "C", C)
    n = A.shape[0]
    _expect("obsv", "C", C, (C.shape[0], n), f"for a {n}-state model")
    t = n if t is None else t
    checks.check_int("obsv", "t", t, minimum=1)
    return ctrb(A.T, C.T, t).T


def gram(sys: StateSpace, type: str = "c") -> jax.Array:
    """Gramian of the stable system ``sys``, as python-control's ``gram(sys, type)``.

    ``type`` 'c': controllability Gramian W (A W + W A^T + B B^T = 0, or A W A^T - W + B B^T = 0 in discrete
    time); 'o': observability (A^T W + W A + C^T C = 0, or its discrete form); 'cf' / 'of': the upper-triangular
    Cholesky factor U with W = U^T U (positive diagonal; W must be definite, i.e. the pair controllable /
    observable, where python-control's SLICOT routine also factors semidefinite Gramians). A system that is not
    strictly stable raises ``ArgumentError`` (a ``ValueError``, like python-control's) on the host path and
    gives NaN under jit."""
    if not isinstance(sys, StateSpace):
        raise checks.ArgumentTypeError(f"gram: sys must be a StateSpace, got {sys.__class__.__name__}")
    checks.check_choice("gram", "type", type, ("c", "o", "cf", "of"))
    A = sys.A
    if type in ("c", "cf"):
        Af, Q = A, sys.B @ sys.B.T
    else:
        Af, Q = A.T, sys.C.T @ sys.C
    discrete = sys.isdtime()
    lam = jnp.linalg.eigvals(A)
    stable = jnp.all(jnp.abs(lam) < 1) if discrete else jnp.all(jnp.real(lam) < 0)
    if checks.is_concrete(A) and not bool(stable):
        checks.fail("gram", "the system is not strictly stable (its Gramians are infinite): eigenvalues of A "
                            + ("on or outside the unit circle" if discrete else "with Re >= 0"))
    W = _dlyap(Af, Q) if discrete else _lyap(Af, Q)
    if type in ("cf", "of"):
        W = jnp.linalg.cholesky(W).T
    return jnp.where(stable, W, jnp.nan)
