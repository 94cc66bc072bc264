"""SPD matrices built from a few free basis vectors and singular values (thesis §2.6.1-2.6.2).

* ``P_v`` (2.19): U_v = [v, R_v e_2, ..., R_v e_d] with the Householder rotation R_v = (I - 2 w w^T)(I - 2 e_1
  e_1^T), w = (-e_1 - v)/||-e_1 - v||, which maps e_1 to v; P_v = U_v diag(s, 1, ..., 1) U_v^T.
* ``P_Vs`` (2.20): the first N basis vectors V are free, the rest come from Gram-Schmidt on
  {v_1..v_N, e_{N+1}..e_d}; P = U diag(s_1..s_N, 1..1) U^T.

Both are smooth in their arguments (away from the measure-zero degenerate cases), so the gradient search of
the ensemble Kalman issue can differentiate through them.
"""

from __future__ import annotations

import jax.numpy as jnp


from jaxdip._public import public_dir

__all__ = ["householder_basis", "P_v", "gram_schmidt_basis", "orthonormalize", "P_Vs", "surface_normal"]
__dir__ = public_dir(globals())


def householder_basis(v):
    """Orthonormal basis whose first column is v / ||v||, via the two reflections of (2.19)."""
    v = jnp.asarray(v, dtype=jnp.float64)
    v = v / jnp.linalg.norm(v)
    d = v.shape[0]
    e1 = jnp.zeros(d).at[0].set(1.0)
    w = -e1 - v
    nw = jnp.linalg.norm(w)
    # v = -e1 makes w vanish; then R_v = I - 2 e1 e1^T itself maps e1 to v
    w = jnp.where(nw > 1e-12, w / jnp.where(nw > 1e-12, nw, 1.0), 0.0)
    R = (jnp.eye(d) - 2.0 * jnp.outer(w, w)) @ (jnp.eye(d) - 2.0 * jnp.outer(e1, e1))
    return R  # R e_1 = v, so the columns [v, R e_2, ..., R e_d] are R itself


def P_v(v, s=1e6):
    """(2.19): SPD matrix with leading singular vector v and singular values [s, 1, ..., 1]."""
    U = householder_basis(v)
    lam = jnp.ones(U.shape[0]).at[0].set(s)
    return (U * lam) @ U.T


def gram_schmidt_basis(V):
    """Orthonormal basis from the columns of V (d x N) completed with e_{N+1}..e_d (modified Gram-Schmidt)."""
    V = jnp.atleast_2d(jnp.asarray(V, dtype=jnp.float64))
    if V.shape[0] < V.shape[1]:
        V = V.T
    d, N = V.shape
    cols = [V[:, i] for i in range(N)] + [jnp.zeros(d).at[i].set(1.0) for i in range(N, d)]
    basis = []
    for c in cols:
        for b in basis:
            c = c - (b @ c) * b
        basis.append(c / jnp.linalg.norm(c))
    return jnp.stack(basis, axis=1)


def orthonormalize(V):
    """The first N columns of ``gram_schmidt_basis``: re-orthonormalised free vectors (Procedure 1)."""
    V = jnp.atleast_2d(jnp.asarray(V, dtype=jnp.float64))
    if V.shape[0] < V.shape[1]:
        V = V.T
    return gram_schmidt_basis(V)[:, : V.shape[1]]


def P_Vs(V, s):
    """(2.20): P = U_V diag(s_1..s_N, 1..1) U_V^T with U_V from Gram-Schmidt on {v_1..v_N, e_{N+1}..e_d}."""
    U = gram_schmidt_basis(V)
    s = jnp.atleast_1d(jnp.asarray(s, dtype=jnp.float64))
    lam = jnp.ones(U.shape[0]).at[: s.shape[0]].set(s)
    return (U * lam) @ U.T


def surface_normal(A, B, poles):
    """Normal c of a sliding hyperplane c^T x = 0 whose reduced (on-surface) dynamics have ``poles``.

    For single-input (A, B), Ackermann's formula for switching surfaces gives c^T = e^T p(A), where e^T is the
    last row of the inverse controllability matrix and p the monic polynomial with the n - 1 ``poles``. A
    projection control whose P maps B onto a multiple of c (e.g. P_v(c, s) with large s) then inherits those
    poles, plus the relaxation's own pole at -gamma in continuous time. Sign chosen so that c^T B > 0.
    """
    A = jnp.asarray(A, dtype=jnp.float64)
    B = jnp.asarray(B, dtype=jnp.float64).reshape(A.shape[0], -1)
    n = A.shape[0]
    if B.shape[1] != 1:
        raise ValueError("surface_normal is for single-input systems")
    if len(poles) != n - 1:
        raise ValueError(f"need {n - 1} poles for a {n}-state system, got {len(poles)}")
    cols = [B]
    for _ in range(n - 1):
        cols.append(A @ cols[-1])
    ctrb = jnp.concatenate(cols, axis=1)
    e = jnp.linalg.solve(ctrb.T, jnp.eye(n)[:, -1])
    coeffs = jnp.real(jnp.poly(jnp.asarray(poles)))
    pA = jnp.zeros_like(A)
    for c in coeffs:  # Horner
        pA = pA @ A + c * jnp.eye(n)
    c = pA.T @ e
    c = c / jnp.linalg.norm(c)
    return c * jnp.sign(c @ B[:, 0])
