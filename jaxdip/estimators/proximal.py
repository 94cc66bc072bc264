"""Least-squares proximal point moving horizon estimation (King thesis §1.3-1.4, Bernstein-King-Tran §2).

Model (thesis (1.17), with the inputs of the paper's (1)):

    x_{k+1} = Phi_k x_k + W_k u_k + eta_k,        y_{k+1} = C_{k+1} x_{k+1} + eps_{k+1}.

Proximal point observer (thesis (1.10)):

    p_k = Prox_{gamma_k phi_k}(xhat_k) = argmin_z  phi_k(z) + 1/(2 gamma_k) ||z - xhat_k||^2,
    xhat_{k+1} = Phi_k p_k + W_k u_k.

Fitting functional. The window of horizon N >= 1 starts at x_k and holds the outputs y_{k+1}, ..., y_{k+N}
(this is the G_k of the thesis; the sum (1.18) printed beside it shifts the output index by one, G_k and v_k are
what the later results use, so they are what is built here). With the transition products

    M_0 = I,   M_i = Phi_{k+i-1} ... Phi_k                    (left-multiplied, latest factor first)
    s_0 = 0,   s_i = Phi_{k+i-1} s_{i-1} + W_{k+i-1} u_{k+i-1} (the state response to the known inputs)

the rows of G_k are C_{k+i} M_i and those of the measurement vector are q_i = y_{k+i} - C_{k+i} s_i, i = 1..N.
For the true trajectory q = G_k x_k + v_k, with v_k the noise vector of the thesis
(v_i = C_{k+i} sum_{j<i} Phi_{k+i-1}...Phi_{k+j+1} eta_{k+j} + eps_{k+i}), so the least-squares fit

    phi_k(z) = 1/2 ||G_k z - q_k||^2 = 1/2 ||G_k (x_k - z) + v_k||^2                      (1.19)

differs from (1.20), 1/2 ||G_k((x_k + zeta_k) - z)||^2 with zeta_k = (G^T G)^{-1} G^T v_k, by a constant only:
both have the same proximal point.

The proximal step is the linear least-squares problem  min || [G; I/sqrt(gamma)] z - [q; xhat/sqrt(gamma)] ||,
solved here by a QR factorisation of the stacked matrix (``prox_ls``) or by the SVD of G (``prox_ls_svd``);
(G^T G + I/gamma) is never formed nor inverted. Note the weight sqrt(1/gamma): Prox_{gamma phi} weighs the
distance term by 1/(2 gamma), so the stacked row block must be I/sqrt(gamma). The thesis's (3.7) prints I/gamma
there, which would be the proximal step of gamma^2; see ``jaxdip.estimators.cpx``.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, param

from jaxdip._public import public_dir

__all__ = ["stacked_system", "qr_factor", "prox_from_qr", "prox_ls", "SVDFactor", "jacobi_svd", "svd_factor",
           "prox_from_svd", "prox_ls_svd", "horizon_stack", "lti_horizon_matrix", "MHETrace", "ls_mhe_filter",
           "LSMHEState", "LSMHEAux", "LeastSquaresMHE"]
__dir__ = public_dir(globals())

# ---- the proximal step --------------------------------------------------------------------------------


def stacked_system(G, q, xhat, gamma):
    """H z ~ r with H = [I/sqrt(gamma); G], r = [xhat/sqrt(gamma); q] (the row order of the thesis's (3.7))."""
    d = G.shape[1]
    s = 1.0 / jnp.sqrt(jnp.asarray(gamma, dtype=G.dtype))
    H = jnp.concatenate([s * jnp.eye(d, dtype=G.dtype), G], axis=0)
    r = jnp.concatenate([s * xhat, q])
    return H, r


def qr_factor(G, gamma):
    """Reduced QR of the stacked matrix H = [I/sqrt(gamma); G]: returns (Q^T, R), Q^T of shape (d, d + rows(G))."""
    H, _ = stacked_system(G, jnp.zeros(G.shape[0], G.dtype), jnp.zeros(G.shape[1], G.dtype), gamma)
    Q, R = jnp.linalg.qr(H, mode="reduced")
    return Q.T, R


def prox_from_qr(QT, R, q, xhat, gamma):
    """The proximal point from a precomputed factorisation: p = R^{-1} Q^T r (a triangular solve)."""
    s = 1.0 / jnp.sqrt(jnp.asarray(gamma, dtype=R.dtype))
    r = jnp.concatenate([s * xhat, q])
    return jsl.solve_triangular(R, QT @ r, lower=False)


def prox_ls(G, q, xhat, gamma):
    """argmin_z 1/2 ||G z - q||^2 + 1/(2 gamma) ||z - xhat||^2, by QR of the stacked matrix."""
    QT, R = qr_factor(G, gamma)
    return prox_from_qr(QT, R, q, xhat, gamma)


class SVDFactor(NamedTuple):
    Ug: jnp.ndarray  # (rows, d) left singular vectors of G
    s: jnp.ndarray  # (d,) singular values, descending: the eigenvalues of G^T G are s**2
    V: jnp.ndarray  # (d, d) right singular vectors = the U_k of the thesis (eigenvectors of G^T G)


def jacobi_svd(G, sweeps: int = 8) -> SVDFactor:
    """One-sided (Hestenes) Jacobi SVD of a small l x d matrix with pure array arithmetic.

    Pairs of columns of U (initially G) are rotated until they are orthogonal; V accumulates the rotations,
    so G V = U, and then s_i = ||U_i||, Ug_i = U_i / s_i. Under vmap this is one fused loop over the batch,
    where ``jnp.linalg.svd`` makes one LAPACK call per item (a few times slower for the 6 x 3 G of the Lorenz
    CPX). Cyclic Jacobi converges quadratically; 8 sweeps leave the columns orthogonal to rounding for d <= 6.
    Rotation for a pair with a = ||u_i||^2, b = ||u_j||^2, g = u_i . u_j: zeta = (b - a)/(2 g),
    t = sign(zeta)/(|zeta| + sqrt(1 + zeta^2)), c = 1/sqrt(1 + t^2), s = c t; u_i <- c u_i - s u_j,
    u_j <- s u_i + c u_j (then u_i . u_j = 0). Zero singular values (rank deficiency, l < d) give Ug_i = 0.
    Singular values come out descending, as from ``jnp.linalg.svd``.
    """
    l, d = G.shape
    U = G
    V = jnp.eye(d, dtype=G.dtype)
    pairs = [(i, j) for i in range(d - 1) for j in range(i + 1, d)]
    # |zeta| bound: zeta^2 must not overflow (1e150 in float64; about 4.6e18 in float32)
    big = jnp.asarray(min(1e150, float(jnp.finfo(G.dtype).max) ** 0.5 / 4), G.dtype)
    one = jnp.ones((), G.dtype)  # a sign in G's dtype (where(c, 1.0, -1.0) would be float64)

    def sweep(_, UV):
        U, V = UV
        for i, j in pairs:
            ui, uj = U[:, i], U[:, j]
            a, b, g = ui @ ui, uj @ uj, ui @ uj
            zero = g == 0.0
            zeta = jnp.clip((b - a) / (2.0 * jnp.where(zero, 1.0, g)), -big, big)
            t = jnp.where(zeta >= 0, one, -one) / (jnp.abs(zeta) + jnp.sqrt(1.0 + zeta * zeta))
            t = jnp.where(zero, 0.0, t)
            c = 1.0 / jnp.sqrt(1.0 + t * t)
            sn = c * t
            U = U.at[:, i].set(c * ui - sn * uj).at[:, j].set(sn * ui + c * uj)
            vi, vj = V[:, i], V[:, j]
            V = V.at[:, i].set(c * vi - sn * vj).at[:, j].set(sn * vi + c * vj)
        return U, V

    U, V = jax.lax.fori_loop(0, sweeps, sweep, (U, V))
    n2 = jnp.sum(U * U, axis=0)
    pos = n2 > 0
    sv = jnp.where(pos, jnp.sqrt(jnp.where(pos, n2, 1.0)), 0.0)
    Ug = jnp.where(pos, U / jnp.where(pos, sv, 1.0), 0.0)
    order = jnp.argsort(-sv)
    return SVDFactor(Ug[:, order], sv[order], V[:, order])


def svd_factor(G, method: str = "lapack") -> SVDFactor:
    """SVD of G with d singular values and d right vectors also when G has fewer rows than columns
    (the missing singular values are 0, their Ug columns 0: those directions keep the prior).
    ``method``: "lapack" (``jnp.linalg.svd``) or "jacobi" (``jacobi_svd``, faster for small batched G)."""
    if method == "jacobi":
        return jacobi_svd(G)
    if method != "lapack":
        raise ValueError(f"svd method must be 'lapack' or 'jacobi', got {method!r}")
    l, d = G.shape
    Ug, s, Vt = jnp.linalg.svd(G, full_matrices=l < d)
    if l < d:
        Ug = jnp.concatenate([Ug, jnp.zeros((l, d - l), G.dtype)], axis=1)
        s = jnp.concatenate([s, jnp.zeros(d - l, G.dtype)])
    return SVDFactor(Ug, s, Vt.T)


def prox_from_svd(f: SVDFactor, q, xhat, gamma, keep: int | None = None):
    """Proximal point in the eigenbasis V of G^T G (thesis §1.6 / (1.26)).

    With a = V^T xhat and b = Ug^T q, coordinate i of V^T p is (gamma s_i b_i + a_i) / (gamma s_i^2 + 1)
    (the same as (s_i b_i + a_i/gamma) / (s_i^2 + 1/gamma), written so that a large gamma costs no precision).
    ``keep`` = p of the subspace estimator: coordinates past the p largest singular values keep a_i, i.e. the
    U_pc U_pc^T xhat term of (1.26). ``keep=None`` is the full least-squares proximal step.
    """
    a = f.V.T @ xhat
    b = f.Ug.T @ q
    g = jnp.asarray(gamma, dtype=a.dtype)
    c = (g * f.s * b + a) / (g * f.s**2 + 1.0)
    if keep is not None:
        mask = jnp.arange(a.shape[0]) < keep
        c = jnp.where(mask, c, a)
    return f.V @ c


def prox_ls_svd(G, q, xhat, gamma, keep: int | None = None, method: str = "lapack"):
    """Same minimiser as ``prox_ls`` (or its subspace restriction with ``keep``), by the SVD of G."""
    return prox_from_svd(svd_factor(G, method), q, xhat, gamma, keep)


# ---- the horizon ----------------------------------------------------------------------------------------


def horizon_stack(Phis, Ws, us, Cs, ys):
    """G_k and q_k of a window of N steps of a linear time-varying model with inputs.

    Phis (N, d, d) = Phi_k .. Phi_{k+N-1};  Ws (N, d, m) and us (N, m) = W, u at k .. k+N-1;
    Cs (N, p, d) = C_{k+1} .. C_{k+N};  ys (N, p) = y_{k+1} .. y_{k+N}.
    Returns G (N p, d) and q (N p,) such that the fit is 1/2 ||G z - q||^2 with z the state at k.
    """
    d = Phis.shape[-1]

    def body(carry, inp):
        M, s = carry
        Phi, W, u, C, y = inp
        M = Phi @ M
        s = Phi @ s + W @ u
        return (M, s), (C @ M, y - C @ s)

    (_, _), (rows, qs) = jax.lax.scan(body, (jnp.eye(d, dtype=Phis.dtype), jnp.zeros(d, Phis.dtype)),
                                      (Phis, Ws, us, Cs, ys))
    return rows.reshape(-1, d), qs.reshape(-1)


def lti_horizon_matrix(Phi, C, N: int):
    """G = [C Phi; C Phi^2; ...; C Phi^N] (the paper's G for (2))."""
    d = Phi.shape[0]
    Phis = jnp.broadcast_to(Phi, (N, d, d))
    Cs = jnp.broadcast_to(C, (N,) + C.shape)
    G, _ = horizon_stack(Phis, jnp.zeros((N, d, 1)), jnp.zeros((N, 1)), Cs, jnp.zeros((N, C.shape[0])))
    return G


# ---- the observer over recorded sequences (LTV) ----------------------------------------------------------


class MHETrace(NamedTuple):
    xhat: jnp.ndarray  # (K + 1, d): xhat_0 .. xhat_K, xhat_k the prior for the window that starts at k
    p: jnp.ndarray  # (K, d): proximal points p_0 .. p_{K-1}, the estimates of x_k


def ls_mhe_filter(gamma, Phis, Ws, us, Cs, ys, xhat0, N: int, method: str = "qr") -> MHETrace:
    """Run the LS proximal MHE (1.10) over recorded sequences of an LTV model.

    Time-indexed inputs: Phis (T, d, d), Ws (T, d, m), us (T, m) for the steps k -> k+1, k = 0..T-1;
    Cs (T + 1, p, d) and ys (T + 1, p) for the outputs at 0..T (index 0 is not used by the windows).
    ``gamma`` is a scalar or a (T - N + 1,) sequence gamma_k. Windows k = 0 .. T-N are processed, so
    K = T - N + 1 proximal points are returned. ``method``: "qr" or "svd".
    """
    T = Phis.shape[0]
    K = T - N + 1
    if K < 1:
        raise ValueError(f"need at least N = {N} steps, got {T}")
    gammas = jnp.broadcast_to(jnp.asarray(gamma, dtype=Phis.dtype), (K,))

    def win(a, k, n):
        return jax.lax.dynamic_slice_in_dim(a, k, n, axis=0)

    def body(xhat, inp):
        k, g = inp
        G, q = horizon_stack(win(Phis, k, N), win(Ws, k, N), win(us, k, N), win(Cs, k + 1, N), win(ys, k + 1, N))
        p = prox_ls(G, q, xhat, g) if method == "qr" else prox_ls_svd(G, q, xhat, g)
        xnext = Phis[k] @ p + Ws[k] @ us[k]
        return xnext, (xnext, p)

    _, (xs, ps) = jax.lax.scan(body, jnp.asarray(xhat0, Phis.dtype), (jnp.arange(K), gammas))
    return MHETrace(xhat=jnp.concatenate([jnp.asarray(xhat0, Phis.dtype)[None], xs]), p=ps)


# ---- online estimator (LTI model) -----------------------------------------------------------------------


class LSMHEState(NamedTuple):
    QT: jnp.ndarray  # offline factorisation of [I/sqrt(gamma); G]
    R: jnp.ndarray
    xstart: jnp.ndarray  # prior estimate of the state at the start of the next window
    ybuf: jnp.ndarray  # (N, p) last N outputs, oldest first
    ubuf: jnp.ndarray  # (N, m) last N inputs, oldest first (ubuf[i] acts between ybuf[i-1] and ybuf[i])
    xhat: jnp.ndarray  # current estimate


class LSMHEAux(NamedTuple):
    xhat: jax.Array  # xhat_j (the output)
    ahead: jax.Array  # Phi xhat_j + W u_{j-1}, the estimate for the next sample with the input held


class LeastSquaresMHE(Estimator):
    """Online LS proximal MHE of horizon N for an LTI model (``Phi``, ``W``, ``C``; weight ``gamma``).

    At sample j (inputs y_j and u_{j-1}) the window starts at x_{j-N} and holds y_{j-N+1} .. y_j. The proximal
    point p_{j-N} is propagated with the model and the buffered inputs to the current estimate xhat_j (the
    output); the prior for the next window is xhat_{j-N+1} = Phi p + W u_{j-N}. Until N outputs have arrived the
    estimate is propagated by the model only. ``aux`` is an ``LSMHEAux``; ``Ahead`` hands out its prediction.
    """

    gamma: jax.Array = param()
    Phi: jax.Array = param()
    W: jax.Array = param()
    C: jax.Array = param()
    xhat0: jax.Array = param()
    N: int = eqx.field(static=True)

    def __check_init__(self):
        checks.check_int(self, "N", self.N, 1)
        d, _, _ = checks.check_lti(self, self.Phi, self.W, self.C)
        checks.check_state_vector(self, "xhat0", self.xhat0, d, f"for a {d}-state model")
        checks.check_ndim(self, "gamma", self.gamma, (0,), "a scalar")
        checks.check_positive(self, "gamma", self.gamma)

    def io_sizes(self) -> dict:
        shape = checks.fmt_shape
        return {"in": (self.C.shape[0], f"C is {shape(self.C.shape)}"),
                "out": (self.Phi.shape[0], f"Phi is {shape(self.Phi.shape)}"),
                "u": (self.W.shape[1], f"W is {shape(self.W.shape)}")}

    def init(self, key, x0):
        G = lti_horizon_matrix(self.Phi, self.C, self.N)
        QT, R = qr_factor(G, self.gamma)
        x_init = jnp.asarray(self.xhat0, dtype=self.Phi.dtype)
        p_dim, m = self.C.shape[0], self.W.shape[1]
        return LSMHEState(QT, R, x_init, jnp.zeros((self.N, p_dim)), jnp.zeros((self.N, m)), x_init)

    def step(self, state, y, u_prev, key, k):
        st, N, Phi, W, C = state, self.N, self.Phi, self.W, self.C
        u_prev = jnp.reshape(u_prev, (W.shape[1],))
        ybuf = jnp.concatenate([st.ybuf[1:], y[None]])
        ubuf = jnp.concatenate([st.ubuf[1:], u_prev[None]])
        d = Phi.shape[0]
        # measurement vector: y_{j-N+i} minus the response to u_{j-N} .. u_{j-N+i-1}
        Phis = jnp.broadcast_to(Phi, (N, d, d))
        Ws = jnp.broadcast_to(W, (N,) + W.shape)
        Cs = jnp.broadcast_to(C, (N,) + C.shape)
        _, q = horizon_stack(Phis, Ws, ubuf, Cs, ybuf)
        full = k >= N
        p = jnp.where(full, prox_from_qr(st.QT, st.R, q, st.xstart, self.gamma), st.xstart)
        # prior of the next window, then forward to the current time with the buffered inputs
        xstart_next = Phi @ p + W @ ubuf[0]

        def fwd(x, u):
            return Phi @ x + W @ u, None

        x_cur, _ = jax.lax.scan(fwd, xstart_next, ubuf[1:])
        # before the first full window: plain model propagation from xhat_0
        x_model = jnp.where(k == 0, st.xhat, Phi @ st.xhat + W @ u_prev)
        xhat = jnp.where(full, x_cur, x_model)
        xstart = jnp.where(full, xstart_next, st.xstart)
        new = LSMHEState(st.QT, st.R, xstart, ybuf, ubuf, xhat)
        return new, xhat, LSMHEAux(xhat, Phi @ xhat + W @ u_prev)
