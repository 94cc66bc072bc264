"""Riccati equations and LQR gains in pure JAX.

python-control's ``K, S, E = lqr(A, B, Q, R)`` and ``dlqr`` are the expected calling convention.

* CARE: the matrix sign function of the Hamiltonian (scaled Newton iteration) gives the stable invariant
  subspace, and Newton-Kleinman steps (a Lyapunov solve each, by Kronecker products: n is at most ~6
  here) polish the solution to machine precision.
* DARE: the structure-preserving doubling algorithm, quadratically convergent for stabilisable/detectable
  pairs.

Both carry custom JVPs by implicit differentiation of the Riccati equation (one Lyapunov/Stein solve per
tangent), so gradients of a closed loop reach the model and the weights without unrolling the iterations.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp


def _f64(*arrs):
    return [jnp.atleast_2d(jnp.asarray(a, dtype=jnp.float64)) for a in arrs]


def lyap(A, Q):
    """Solve A^T X + X A + Q = 0 (A Hurwitz) by the Kronecker form; fine for the small n of pendulums."""
    n = A.shape[0]
    I = jnp.eye(n)
    L = jnp.kron(I, A.T) + jnp.kron(A.T, I)
    x = jnp.linalg.solve(L, -Q.reshape(-1))
    X = x.reshape(n, n)
    return 0.5 * (X + X.T)


def stein(A, Q):
    """Solve X = A^T X A + Q (A Schur-stable) by the Kronecker form."""
    n = A.shape[0]
    L = jnp.eye(n * n) - jnp.kron(A.T, A.T)
    X = jnp.linalg.solve(L, Q.reshape(-1)).reshape(n, n)
    return 0.5 * (X + X.T)


def care(A, B, Q, R, sign_iters: int = 60, newton_iters: int = 3):
    """Stabilising solution X of A^T X + X A - X B R^-1 B^T X + Q = 0 (differentiable in A, B, Q, R)."""
    return _care(*_f64(A, B, Q, R), sign_iters, newton_iters)


@partial(jax.custom_jvp, nondiff_argnums=(4, 5))
def _care(A, B, Q, R, sign_iters, newton_iters):
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
        return lyap(Acl, Q + K.T @ R @ K)

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
    return X, lyap(Acl, 0.5 * (rhs + rhs.T))


def dare(A, B, Q, R, iters: int = 40):
    """Stabilising solution X of X = A^T X A - A^T X B (R + B^T X B)^-1 B^T X A + Q (doubling algorithm;
    differentiable in A, B, Q, R)."""
    return _dare(*_f64(A, B, Q, R), iters)


@partial(jax.custom_jvp, nondiff_argnums=(4,))
def _dare(A, B, Q, R, iters):
    n = A.shape[0]
    I = jnp.eye(n)
    G = B @ jnp.linalg.solve(R, B.T)

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
    return X, stein(Acl, 0.5 * (rhs + rhs.T))


def lqr(A, B, Q, R):
    """Continuous LQR: returns (K, S, E) with u = -K x, S the CARE solution, E the closed-loop eigenvalues."""
    A, B, Q, R = _f64(A, B, Q, R)
    S = care(A, B, Q, R)
    K = jnp.linalg.solve(R, B.T @ S)
    E = jnp.linalg.eigvals(A - B @ K)
    return K, S, E


def dlqr(A, B, Q, R):
    """Discrete LQR: returns (K, S, E) with u_k = -K x_k."""
    A, B, Q, R = _f64(A, B, Q, R)
    S = dare(A, B, Q, R)
    K = jnp.linalg.solve(R + B.T @ S @ B, B.T @ S @ A)
    E = jnp.linalg.eigvals(A - B @ K)
    return K, S, E
