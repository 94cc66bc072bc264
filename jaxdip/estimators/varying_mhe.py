"""Weighted proximal MHE for time-varying linear models and for nonlinear models linearised along the estimate.

The window problem of ``WeightedMHE`` (``jaxdip.estimators.weighted_mhe``) with a model that changes from sample to
sample, posed in the window's states themselves: at sample j the unknown is Z = (z_0 .. z_N) = x_{j-N} .. x_j and
the estimate minimises

    1/2 sum_{i=0..N} ||y'_i - C_i z_i||^2_{Wv}  +  1/2 sum_{i<N} ||z_{i+1} - Phi_i z_i - W_i u_i - c_i||^2_{Ww}
        +  1/(2 gamma) ||z_a - xbar||^2_{Wa}                                     (lower <= z_i <= upper, A_c z_i <= b_c)

(Phi_i, W_i, c_i the transition x_{j-N+i} -> x_{j-N+i+1}, C_i and y'_i the output at sample j-N+i). The dynamics
are soft terms between neighbouring states, so nothing is propagated backwards: no Phi^{-1} is formed, and a
singular Phi_i (a delay, a sample-and-hold) is allowed. The stacked matrix changes every sample, so it is
factorised by QR at every step (the LTI ``WeightedMHE`` factorises once in ``init``).

Models (indexing: entry k of a stack belongs to sample k; past the end of a stack its last entry is used):
* time-varying linear: ``Phi`` (T, d, d) and ``W`` (T, d, m) with x_{k+1} = Phi[k] x_k + W[k] u_k + w_k, ``C``
  (T, p, d) with y_k = C[k] x_k + v_k; any of them may be a single matrix (time-invariant). c_i = 0, y'_i = y_i.
* nonlinear, ``f(x, u)`` (a discrete map, e.g. ``lambda x, u: plant.period(x, u, dt, substeps)``) and/or
  ``h(x)``: linearised along the estimate as each sample arrives, as the EKF does: the transition
  k-1 -> k at the unconstrained estimate of x_{k-1} (Phi = df/dx, W = df/du, c = f - Phi x - W u), the output of
  sample k at the one-step prediction of x_k (C = dh/dx, y' = y - h + C x). The window keeps the linearisations of
  its samples, so each window is the weighted least squares of the model linearised along the estimates.

The prior xbar of the anchor z_a is the filtered one of ``WeightedMHE`` (``prior="filtered"``): the estimator's
one-step prediction of x_{j-N+a} made before y_{j-N+a} arrived, propagated from the unconstrained estimates. Before
the first full window (j < N) the estimate is the model's propagation of xhat0. ``aux.window`` is the window's
solution Z (N + 1, d) (row i estimates x_{j-N+i}; zeros before the first full window), ``aux.prior`` the xbar it
used. Constraints on every window state are solved by the dual active-set method of ``WeightedMHE``
(``jaxdip.estimators.active_set``); ``aux.violation`` is the KKT residual left.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from jaxdip._public import public_dir
from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, param, dtype_of
from jaxdip.estimators._weighted_mhe_checks import bounded_coordinates
from jaxdip.estimators.active_set import dual_active_set

__all__ = ["TVMHEState", "TVMHEAux", "TimeVaryingMHE", "window_matrix", "window_vector"]
__dir__ = public_dir(globals())


class TVMHEState(NamedTuple):
    xcur: jax.Array  # current estimate of x_j
    xchain: jax.Array  # the unconstrained estimate of x_j, which priors and linearisations are propagated from
    pbuf: jax.Array  # (N + 1, d) one-step predictions xhat_{t|t-1}, t = j-N .. j
    ybuf: jax.Array  # (N + 1, p) y'_{j-N} .. y'_j (linearised measurements for a nonlinear h)
    ubuf: jax.Array  # (N, m) u_{j-N} .. u_{j-1}
    Cbuf: jax.Array  # (N + 1, p, d) C_{j-N} .. C_j
    Phibuf: jax.Array  # (N, d, d) transitions of the window
    Wbuf: jax.Array  # (N, d, m)
    cbuf: jax.Array  # (N, d) affine remainders of linearised transitions (zero for a linear model)


class TVMHEAux(NamedTuple):
    xhat: jax.Array  # current estimate x_j (the output)
    window: jax.Array  # (N + 1, d) the window solution, row i estimating x_{j-N+i}
    prior: jax.Array  # the anchor prior xbar of this window
    violation: jax.Array  # KKT residual of the constrained step (0 unconstrained or converged)


def _at(stack, k, ndim: int):
    """Entry k of a per-sample stack (clamped to its range), or the matrix itself when it is not a stack."""
    if stack.ndim == ndim:
        return stack
    return stack[jnp.clip(k, 0, stack.shape[0] - 1)]


def _sqrt_weight(Wt):
    return jnp.linalg.cholesky(Wt).T


def window_matrix(Sa, Sv, Sw, Cs, Phis, anchor: int) -> jax.Array:
    """The stacked matrix of the window problem in Z = (z_0 .. z_N), the weights by their square roots (S^T S =
    weight; Sa already scaled by 1/sqrt(gamma)): rows arrival (Sa on z_anchor), measurements Sv C_i z_i
    (i = 0..N), process Sw (z_{i+1} - Phi_i z_i) (i < N). Shared with the full form of ``WeightedMHE``."""
    N, d = len(Phis), Sa.shape[0]
    n = d * (N + 1)
    dt = Sa.dtype
    arr = jnp.zeros((d, n), dt).at[:, anchor * d:(anchor + 1) * d].set(Sa)
    meas = jsl.block_diag(*[Sv @ Cs[i] for i in range(N + 1)])
    proc = jnp.zeros((N * d, n), dt)
    for i in range(N):
        proc = proc.at[i * d:(i + 1) * d, i * d:(i + 1) * d].set(-Sw @ Phis[i])
        proc = proc.at[i * d:(i + 1) * d, (i + 1) * d:(i + 2) * d].set(Sw)
    return jnp.concatenate([arr, meas, proc], axis=0)


def window_vector(Sa, Sv, xbar, ys, white_drives) -> jax.Array:
    """The right-hand side of ``window_matrix``'s rows: Sa xbar, Sv y_i, and the process rows' known drive
    Sw (W_i u_i + c_i), given whitened (``white_drives`` (N, d)) so each caller keeps its own product order."""
    return jnp.concatenate([Sa @ xbar, (ys @ Sv.T).reshape(-1), white_drives.reshape(-1)])


class TimeVaryingMHE(Estimator):
    """Weighted proximal MHE of horizon N over a time-varying or linearised model (module docstring).

    Give ``Phi`` and ``W`` (matrices or per-sample stacks) or a map ``f(x, u)``, and ``C`` (matrix or stack) or a
    map ``h(x)``. ``meas_weight`` (p, p), ``proc_weight`` (d, d), ``arrival_weight`` (d, d), ``gamma`` as in
    ``WeightedMHE``; ``N``, ``anchor``, ``box_iters`` static. ``from_noise`` takes (Q, R, P) as ``WeightedMHE``'s.
    """

    Phi: Optional[jax.Array]
    W: Optional[jax.Array]
    C: Optional[jax.Array]
    meas_weight: jax.Array = param()
    proc_weight: jax.Array = param()
    arrival_weight: jax.Array = param()
    gamma: jax.Array = param()
    xhat0: jax.Array = param()
    lower: jax.Array = param()
    upper: jax.Array = param()
    A_c: Optional[jax.Array]
    b_c: Optional[jax.Array]
    N: int = eqx.field(static=True)
    anchor: int = eqx.field(static=True)
    n_inputs: int = eqx.field(static=True)
    box_rows: tuple = eqx.field(static=True)
    box_iters: Optional[int] = eqx.field(static=True)
    f: Optional[Callable] = eqx.field(static=True)
    h: Optional[Callable] = eqx.field(static=True)

    def __init__(self, meas_weight, proc_weight, arrival_weight, gamma=1.0, *, Phi=None, W=None, C=None,
                 f: Optional[Callable] = None, h: Optional[Callable] = None, N: int = 2, anchor: int = 0,
                 xhat0=None, n_inputs: Optional[int] = None, lower=None, upper=None, A_c=None, b_c=None,
                 box_iters: Optional[int] = None):
        fl = jnp.result_type(float)
        for name, v in (("meas_weight", meas_weight), ("proc_weight", proc_weight),
                        ("arrival_weight", arrival_weight), ("gamma", gamma), ("Phi", Phi), ("W", W), ("C", C),
                        ("xhat0", xhat0), ("A_c", A_c), ("b_c", b_c)):
            if v is not None:
                checks.check_real(self, name, v)
        if (Phi is None) == (f is None):
            checks.fail(self, "give the transition either as Phi (and W) or as a map f(x, u), not both or neither")
        if (C is None) == (h is None):
            checks.fail(self, "give the output either as C or as a map h(x), not both or neither")
        if (A_c is None) != (b_c is None):
            checks.fail(self, "give both A_c and b_c (affine constraints A_c z <= b_c) or neither")
        checks.check_int(self, "N", N, 1)
        checks.check_int(self, "anchor", anchor, 0)
        if not anchor < N:
            checks.fail(self, f"anchor must satisfy 0 <= anchor < N = {N}, got {anchor}")
        as_f = lambda v: None if v is None else jnp.asarray(v, fl)
        self.Phi, self.C, self.f, self.h = as_f(Phi), as_f(C), f, h
        d = checks.check_square(self, "proc_weight", proc_weight)
        if n_inputs is None:
            n_inputs = 1 if W is None else int(jnp.shape(W)[-1])
        self.W = None if Phi is None else (jnp.zeros((d, n_inputs), fl) if W is None else as_f(W))
        self.meas_weight, self.proc_weight, self.arrival_weight, self.gamma = (
            meas_weight, proc_weight, arrival_weight, gamma)
        self.xhat0 = jnp.zeros(d) if xhat0 is None else xhat0
        self.lower = jnp.full(d, -jnp.inf) if lower is None else lower
        self.upper = jnp.full(d, jnp.inf) if upper is None else upper
        self.box_rows = bounded_coordinates(self.lower, self.upper) if (lower is not None or upper is not None) else ()
        self.A_c = None if A_c is None else jnp.atleast_2d(as_f(A_c))
        self.b_c = None if b_c is None else jnp.atleast_1d(as_f(b_c))
        self.N, self.anchor, self.n_inputs, self.box_iters = N, anchor, n_inputs, box_iters

    def __check_init__(self):
        d = self.proc_weight.shape[0]
        why = f"for a {d}-state model (proc_weight is {checks.fmt_shape(self.proc_weight.shape)})"
        checks.check_covariance(self, "proc_weight", self.proc_weight, d, why)
        checks.check_covariance(self, "arrival_weight", self.arrival_weight, d, why)
        checks.check_square(self, "meas_weight", self.meas_weight)
        checks.check_psd(self, "meas_weight", self.meas_weight)
        p = self.meas_weight.shape[0]
        if self.Phi is not None:
            checks.check_shape(self, "Phi", self.Phi, (None,) * (self.Phi.ndim - 2) + (d, d), why)
            checks.check_shape(self, "W", self.W, (None,) * (self.W.ndim - 2) + (d, self.n_inputs), why)
        if self.C is not None:
            checks.check_shape(self, "C", self.C, (None,) * (self.C.ndim - 2) + (p, d),
                               f"for {p} measurements (meas_weight is {checks.fmt_shape(self.meas_weight.shape)})")
        checks.check_ndim(self, "gamma", self.gamma, (0,), "a scalar")
        checks.check_positive(self, "gamma", self.gamma)
        checks.check_state_vector(self, "xhat0", self.xhat0, d, why)
        for name in ("lower", "upper"):
            checks.check_shape(self, name, getattr(self, name), (d,), why)
        checks.check_limits(self, "lower", self.lower, "upper", self.upper)
        if self.A_c is not None:
            checks.check_shape(self, "A_c", self.A_c, (None, d), why)
            checks.check_shape(self, "b_c", self.b_c, (self.A_c.shape[0],), "(one bound per row of A_c)")

    def io_sizes(self) -> dict:
        d, p = self.proc_weight.shape[0], self.meas_weight.shape[0]
        return {"in": (p, f"meas_weight is ({p}, {p})"), "out": (d, f"proc_weight is ({d}, {d})"),
                "u": (self.n_inputs, f"{self.n_inputs} inputs")}

    @classmethod
    def from_noise(cls, Q, R, P, N: int, **kw) -> "TimeVaryingMHE":
        """Gaussian weights: Wv = R^{-1}, Ww = Q^{-1}, Wa = P^{-1} (P the prior covariance of the anchor)."""
        inv = lambda M: jnp.linalg.inv(jnp.asarray(M, jnp.result_type(float)))
        return cls(inv(R), inv(Q), inv(P), 1.0, N=N, **kw)

    # ---- the window problem ----------------------------------------------------------------------------------

    def stacked(self, xbar, ybuf, ubuf, Cbuf, Phibuf, Wbuf, cbuf):
        """(A, b) of min ||A Z - b||^2 in Z = (z_0 .. z_N): rows arrival, measurements i = 0..N, process i < N."""
        dt = ybuf.dtype
        Sa = _sqrt_weight(self.arrival_weight) / jnp.sqrt(jnp.asarray(self.gamma, dt))
        Sv, Sw = _sqrt_weight(self.meas_weight), _sqrt_weight(self.proc_weight)
        drive = jnp.einsum("idm,im->id", Wbuf, ubuf) + cbuf
        return window_matrix(Sa, Sv, Sw, Cbuf, Phibuf, self.anchor), window_vector(Sa, Sv, xbar, ybuf, drive @ Sw.T)

    @property
    def constrained(self) -> bool:
        return bool(self.box_rows) or self.A_c is not None

    def constraint_matrix(self):
        """(G, lo, hi): lo <= G Z <= hi, the box rows then the A_c rows of each window state i = 0 .. N."""
        d = self.proc_weight.shape[0]
        dt = self.xhat0.dtype
        rows = []
        if self.box_rows:
            i = np.asarray(self.box_rows, dtype=int)
            rows.append((jnp.eye(d, dtype=dt)[i], self.lower[i], self.upper[i]))
        if self.A_c is not None:
            rows.append((self.A_c, jnp.full(self.b_c.shape, -jnp.inf, dt), self.b_c))
        E, lo, hi = (jnp.concatenate([r[j] for r in rows]) for j in range(3))
        return jnp.kron(jnp.eye(self.N + 1, dtype=dt), E), jnp.tile(lo, self.N + 1), jnp.tile(hi, self.N + 1)

    def solve_window(self, A, b):
        """(unconstrained Z, constrained Z, KKT residual) of the window (A, b)."""
        Qm, R = jnp.linalg.qr(A, mode="reduced")
        X = jsl.solve_triangular(R, Qm.T @ b, lower=False)
        if not self.constrained:
            return X, X, jnp.zeros((), X.dtype)
        G, lo, hi = self.constraint_matrix()
        V = jsl.solve_triangular(R, G.T, trans="T", lower=False)  # R^{-T} G^T
        K, M = jsl.solve_triangular(R, V, lower=False), V.T @ V
        iters = 2 * G.shape[0] + 2 if self.box_iters is None else self.box_iters
        Xc, viol = dual_active_set(G, lo, hi, K, M, R, X, jnp.zeros(G.shape[0], X.dtype), iters)
        return X, Xc, viol

    # ---- linearisation as samples arrive -----------------------------------------------------------------------

    def transition(self, x, u, k):
        """(Phi, W, c) of the transition x_k -> x_{k+1} at the estimate x (c = 0 for a linear model)."""
        if self.f is None:
            return _at(self.Phi, k, 2), _at(self.W, k, 2), jnp.zeros_like(x)
        Phi, W = jax.jacfwd(self.f, argnums=(0, 1))(x, u)
        W = W.reshape(x.shape[0], u.shape[0])
        return Phi, W, self.f(x, u) - Phi @ x - W @ u

    def output(self, y, x, k):
        """(C, y') of sample k linearised at the prediction x (y' = y for a linear output)."""
        if self.h is None:
            return _at(self.C, k, 2), y
        C = jax.jacfwd(self.h)(x)
        return C, y - self.h(x) + C @ x

    # ---- the engine protocol -----------------------------------------------------------------------------------

    def init(self, key, x0):
        d, p, m, N = self.proc_weight.shape[0], self.meas_weight.shape[0], self.n_inputs, self.N
        x = jnp.asarray(self.xhat0, dtype=dtype_of(x0))
        z = lambda *s: jnp.zeros(s, x.dtype)
        return TVMHEState(x, x, z(N + 1, d), z(N + 1, p), z(N, m), z(N + 1, p, d), z(N, d, d), z(N, d, m), z(N, d))

    def step(self, state: TVMHEState, y, u_prev, key, k):
        N, a = self.N, self.anchor
        p = self.meas_weight.shape[0]
        u_prev = jnp.reshape(jnp.asarray(u_prev, state.xcur.dtype), (self.n_inputs,))
        first = k == 0
        Phi, W, c = self.transition(state.xchain, u_prev, k - 1)
        x_model = jnp.where(first, state.xcur, Phi @ state.xcur + W @ u_prev + c)
        x_chain = jnp.where(first, state.xchain, Phi @ state.xchain + W @ u_prev + c)  # xhat_{k|k-1}
        C, y_lin = self.output(jnp.reshape(y, (p,)), x_chain, k)
        shift = lambda buf, new: jnp.concatenate([buf[1:], new[None]])
        st = TVMHEState(state.xcur, state.xchain, shift(state.pbuf, x_chain), shift(state.ybuf, y_lin),
                        shift(state.ubuf, u_prev), shift(state.Cbuf, C), shift(state.Phibuf, Phi),
                        shift(state.Wbuf, W), shift(state.cbuf, c))
        xbar = st.pbuf[a]
        A, b = self.stacked(xbar, st.ybuf, st.ubuf, st.Cbuf, st.Phibuf, st.Wbuf, st.cbuf)
        X_free, X, violation = self.solve_window(A, b)
        d = self.proc_weight.shape[0]
        full = k >= N
        xcur = jnp.where(full, X[N * d:], x_model)
        xchain = jnp.where(full, X_free[N * d:], x_chain)
        window = jnp.where(full, X.reshape(N + 1, d), 0.0)
        aux = TVMHEAux(xcur, window, xbar, jnp.where(full, violation, 0.0))
        return st._replace(xcur=xcur, xchain=xchain), xcur, aux
