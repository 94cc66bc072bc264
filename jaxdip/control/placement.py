"""Pole placement: ``acker`` (Ackermann's formula, single input) and ``place`` (eigenvector assignment, any number
of inputs), as python-control's ``acker`` and ``place``; u = -K x puts the eigenvalues of A - B K at the poles.

``place`` assigns a closed loop A - B K = X diag(p) X^-1: each eigenvector x_j must lie in the subspace
S_j = null(U1^T (A - p_j I)) (U1 spanning the complement of range B), so that A - (closed loop) lies in range B.
With one input S_j is a line and the gain is unique (it equals Ackermann's and python-control's). With m > 1
inputs the gain is not unique: python-control runs Tits and Yang's algorithm (via SciPy), jaxdip a fixed number
of sweeps of Kautsky, Nichols and Van Dooren's rank-one method 0 (each x_j in turn is replaced by the projection
onto S_j of the direction orthogonal to the other eigenvectors), which keeps X well conditioned; the two gains
differ, their closed-loop poles agree. Complex poles must come in conjugate pairs; each pair gets conjugate
eigenvectors so K is real.

Differentiability: both are smooth in A, B and the poles where the poles are distinct (with one input) or of
multiplicity at most m; at a pole of multiplicity above m no diagonalisable closed loop exists. Errors: on the
host path an unreachable (A, B) raises ``ArgumentError`` (a ``ValueError``, the class of python-control's), as do
poles not in conjugate pairs, of the wrong number or repeated more than rank(B) times. Under jit nothing is checked:
where no placement exists the eigenvector matrix is singular and the gain huge or not finite, so check
eig(A - B K) there.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.control.lyapunov import ctrb
from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["acker", "place"]
__dir__ = public_dir(globals())

_SWEEPS = 8  # KNV method-0 sweeps: the conditioning of X settles within a few


def _args(owner: str, A, B, poles):
    for name, v in (("A", A), ("B", B), ("poles", poles)):
        checks.check_finite(owner, name, v) if name != "poles" else None
    checks.check_real(owner, "A", A)
    checks.check_real(owner, "B", B)
    A = jnp.atleast_2d(jnp.asarray(A, dtype=jnp.float64))
    n = checks.check_square(owner, "A", A)
    B = jnp.asarray(B, dtype=jnp.float64)
    B = B.reshape(n, -1) if B.ndim < 2 else B
    checks.check_shape(owner, "B", B, (n, None), f"for a {n}-state model")
    poles = jnp.atleast_1d(jnp.squeeze(jnp.asarray(poles)))
    if poles.shape != (n,):
        checks.fail(owner, f"poles must hold {n} values for a {n}-state model, got shape "
                           f"{checks.fmt_shape(poles.shape)}")
    if checks.is_concrete(A, B, poles):
        p = np.asarray(poles, dtype=complex)
        if not np.all(np.isfinite(p)):
            checks.fail(owner, "poles must be finite")
        if not np.allclose(np.sort_complex(p), np.sort_complex(p.conj()), rtol=1e-12, atol=0):
            checks.fail(owner, "complex poles must come in conjugate pairs (a real gain cannot place them)")
        ct = np.asarray(ctrb(A, B))
        if np.linalg.matrix_rank(ct) != n:
            checks.fail(owner, "(A, B) is not reachable (the controllability matrix has rank "
                               f"{np.linalg.matrix_rank(ct)} < {n}), so no gain places all poles")
    return A, B, poles


def acker(A, B, poles) -> jax.Array:
    """Ackermann's gain for a single input: K = e_n^T ctrb(A, B)^-1 phi(A), phi the polynomial with roots
    ``poles``. Returns shape (n,) as python-control's ``acker``."""
    A, B, poles = _args("acker", A, B, poles)
    if B.shape[1] != 1:
        checks.fail("acker", f"B must have a single column (Ackermann's formula is single-input; use place), "
                             f"got {B.shape[1]}")
    return _acker(A, B, poles)


@jax.jit
def _acker(A, B, poles):
    n = A.shape[0]
    c = jnp.real(jnp.poly(poles))
    P = jnp.eye(n)
    for ci in c[1:]:  # Horner: phi(A) = (...((A + c1 I) A + c2 I) ...) + cn I
        P = P @ A + ci * jnp.eye(n)
    return jnp.linalg.solve(ctrb(A, B), P)[-1]


def place(A, B, poles) -> jax.Array:
    """Gain K (m, n) with eig(A - B K) = ``poles``, as python-control's ``place`` (see the module notes for how
    its MIMO gain differs)."""
    A, B, poles = _args("place", A, B, poles)
    if checks.is_concrete(B, poles):
        rank = np.linalg.matrix_rank(np.asarray(B))
        p = np.asarray(poles, dtype=complex)
        mult = max(int(np.sum(np.abs(p - q) <= 1e-12 * max(1.0, abs(q)))) for q in p)
        pairs = [q for q in p if q.imag != 0]
        if m_complex := max((int(np.sum(np.abs(p - q) <= 1e-12 * abs(q))) for q in pairs), default=0) > 1:
            checks.fail("place", f"a complex pole pair is repeated {m_complex} times: not supported (python-control's "
                                 "place supports it)")
        if mult > rank:
            checks.fail("place", f"a pole is repeated {mult} times, more than rank(B) = {rank}: no diagonalisable "
                                 "closed loop has it")
    return _place(A, B, poles)


@jax.jit
def _place(A, B, poles):
    n, m = B.shape
    U, Rb = jnp.linalg.qr(B, mode="complete")
    U0, U1, Z = U[:, :m], U[:, m:], Rb[:m]
    # conjugate pairs next to each other, the one with negative imaginary part first (jit-safe: no static pairs)
    p = poles.astype(complex)
    p = p[jnp.lexsort((jnp.imag(p), jnp.abs(jnp.imag(p)), jnp.real(p)))]
    second = jnp.imag(p) > 0  # the conjugate of the pole before it
    I = jnp.eye(n, dtype=complex)

    Ms = jax.vmap(lambda lam: U1.T @ (A - lam * I))(p)  # S_j = null(M_j)

    def project(j, y):
        # the projection onto S_j, applied twice: once leaves a residual M y of order eps cond(M)^2, the second
        # pass removes it (the closed-loop poles are only as accurate as x_j lies in S_j)
        M = Ms[j]
        if M.shape[0] == 0:
            return y
        for _ in range(2):
            y = y - M.conj().T @ jnp.linalg.solve(M @ M.conj().T, M @ y)
        return y

    # a fixed, generic start (the same for every call, so the gain is a function of its arguments)
    T = jnp.asarray(np.random.default_rng(0).standard_normal((n, n)), dtype=complex)
    X = jax.vmap(project, in_axes=(0, 1), out_axes=1)(jnp.arange(n), T)

    def column(j, X):
        y = jnp.linalg.inv(X)[j].conj()  # orthogonal to every column of X but the j-th
        x = project(j, y)
        x = jnp.where(second[j], X[:, j - 1].conj(), x / jnp.linalg.norm(x))
        return X.at[:, j].set(x)

    def sweep(_, X):
        X = X / jnp.linalg.norm(X, axis=0)
        X = jnp.where(second[None, :], jnp.roll(X, 1, axis=1).conj(), X)
        return jax.lax.fori_loop(0, n, column, X)

    X = jax.lax.fori_loop(0, _SWEEPS, sweep, X) if m > 1 else X
    Acl = jnp.real(X @ jnp.diag(p) @ jnp.linalg.inv(X))
    return jax.scipy.linalg.solve_triangular(Z, U0.T @ (A - Acl), lower=False)
