"""Weighted proximal moving horizon estimation: noise weights, an arrival cost, box and affine constraints
(LTI model).

Window at sample j (the estimator receives y_j and u_{j-1}): states z_0 .. z_N = x_{j-N} .. x_j, outputs
y_{j-N} .. y_j, inputs u_{j-N} .. u_{j-1}. With x_{i+1} = Phi x_i + W u_i + w_i, y_i = C x_i + v_i, the
estimate is the minimiser of the stacked weighted least squares

    1/2 sum_{i=0..N} ||y_i - C z_i||^2_{Wv}  +  1/2 sum_{i<N} ||z_{i+1} - Phi z_i - W u_i||^2_{Ww}
        +  1/(2 gamma) ||z_a - xbar||^2_{Wa}                                           (lo <= z_i <= hi)

i.e. the proximal point, in the metric Wa / gamma, of the window's fitting functional at the prior xbar of the
anchor state z_a (0 <= a < N): the proximal term *is* the arrival cost. Wv = R^{-1} and Ww = Q^{-1} are the
true noise weights of a Gaussian model (``WeightedMHE.from_noise``); with Wa = P^{-1}, P the stationary
a-priori covariance of the Kalman filter, and gamma = 1 this is the usual MHE with a fixed arrival cost.

Two forms.
* ``proc_weight`` given: the unknown is the whole window trajectory Z = (z_0 .. z_N), d (N + 1) numbers.
* ``proc_weight=None``: the model is a hard constraint (no process noise), the unknown is z_a alone, and
  z_i = Phi^{i-a} z_a + s_i (s_i the response to the known inputs, backwards through Phi^{-1}). With Wv = I,
  Wa = I, N = 2, a = 1 the stacked matrix is exactly the [I/sqrt(gamma); C Phi^{-1}; C; C Phi] of CPX
  (``jaxdip.estimators.cpx``), row for row, and the estimator is CPX (tested to rounding). A weight on the
  whole window's measurement residual, given by its square root ``window_sqrt``, adds SCPX: with the
  projector onto the p leading left singular vectors of G (``WeightedMHE.scpx``) the estimator is SCPX.

Either way the problem is min ||A X - b||^2 with A fixed (LTI model, static N): A is factorised once by QR in
``init`` (a differentiable function of every weight, so gradients and sweeps need no recompilation). Each step
is then one product with Q^T and a triangular solve, as in the thesis's (3.7)-(3.8), merged into the precomputed
R^{-1} Q^T (one matrix-vector product); with constraints that product is the starting point of the QP below.

The current estimate is z_N (with the hard model: z_a propagated to j). The prior xbar of the anchor comes in
two kinds (static ``prior``):
* "smoothed" (CPX, the thesis's (3.8)): the previous window's anchor solution propagated, Phi z_a + W u_{j-N+a}.
  It has already used y_{j-N+a} .. y_{j-1}, which the new window uses again.
* "filtered": the estimator's own one-step prediction of x_{j-N+a} made before y_{j-N+a} arrived,
  xhat_{j-N+a|j-N+a-1} = Phi xhat_{j-N+a-1} + W u (a buffer of the last N + 1 predictions). With a = 0 no
  measurement is counted twice; with Wa = P^{-1} (P the stationary a-priori KF covariance), Wv = R^{-1},
  Ww = Q^{-1}, gamma = 1, no active constraint, each window is the stationary (fixed-gain) Kalman filter run from
  the window's prior, so the estimate *converges* to that filter's: the difference obeys d_j =
  [(I - K C) Phi]^{N+1} d_{j-N-1} (the first N estimates are propagations), tested. Measured on the linearised
  DIP the smoothed prior with the same weights had 1.67x the KF's velocity RMS error (the double-counted
  measurements are weighed as if new), the filtered one matches it (tests/test_weighted_mhe.py).
Before the first full window (j < N) the estimate is the model's propagation of xhat_0, and the smoothed prior
waits at xhat_0 until its time index reaches 0.

Nonlinear output map ``h(x)`` (instead of C): linearised along the prior propagated through the window by the
model, zb_a = xbar, zb_{i+1} = Phi zb_i + W u_i, so y_i - h(zb_i) + H_i zb_i ~ H_i z_i with H_i = dh/dx(zb_i)
(forward-mode autodiff): one Gauss-Newton step from the prior, the MHE analogue of the EKF's linearisation at
the predicted mean. The stacked matrix then changes every step and is factorised every step.

Constraints on every window state z_i: a box ``lower <= z_i <= upper`` and affine rows ``A_c z_i <= b_c``.
In the unknown X of either form they are rows lo <= G X + c <= hi: the full form has G = I (box) and
blockdiag(A_c) (affine), c = 0; the hard-model form has z_i = Phi^{i-a} z_a + s_i, so G stacks Phi^{i-a} and
A_c Phi^{i-a}, and c (the input response s_i) changes every step. The proximal step is then a strictly convex QP, solved by the dual active-set method of
``jaxdip.estimators.active_set`` (why that method: its docstring). A fixed number of iterations (``box_iters``,
default 2 x rows + 2) keeps it a static program under jit/vmap; ``aux.violation`` reports the KKT residual left.

The filtered prior is propagated from the *unconstrained* window estimate. Feeding the constrained estimates
back instead biases the arrival cost towards the interior of the box whenever the truth sits on a bound (every
truncation pushes the same way), and measured on the test problem that bias cancelled the gain of the bound;
with the unconstrained chain the constrained estimate is the box-constrained MAP under the same prior the
unconstrained (KF-equivalent) estimator uses.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from jaxdip._public import public_dir
from jaxdip.engine.roles import Estimator, param, dtype_of
from jaxdip.estimators import _weighted_mhe_checks as validation
from jaxdip.estimators.active_set import dual_active_set
from jaxdip.estimators.varying_mhe import window_matrix, window_vector
from jaxdip.sim.discretize import Discrete

__all__ = ["WMHEState", "WMHEAux", "WeightedMHE"]
__dir__ = public_dir(globals())


class WMHEState(NamedTuple):
    factor: tuple  # (R^{-1} Q^T,) of the stacked matrix A = Q R; with constraints also R and (K, M)
    xbar: jax.Array  # prior of the next window's anchor state
    ybuf: jax.Array  # (N + 1, p) y_{j-N} .. y_j
    ubuf: jax.Array  # (N, m) u_{j-N} .. u_{j-1}
    xcur: jax.Array  # current estimate of x_j
    pbuf: jax.Array  # (N + 1, d) one-step predictions xhat_{t|t-1}, t = j-N .. j (prior="filtered")
    xchain: jax.Array  # the estimate of x_j the priors are propagated from (the unconstrained one, see above)


class WMHEAux(NamedTuple):
    xhat: jax.Array  # current estimate x_j (the output)
    ahead: jax.Array  # Phi x_j + W u_{j-1}, the prediction with the input held (``Ahead``)
    violation: jax.Array  # KKT residual of the constrained step (0 unconstrained or converged)
    window: jax.Array  # (N + 1, d) the window solution, row i estimating x_{j-N+i} (zeros while j < N)


def _sqrt_weight(Wt):
    """S with S^T S = Wt (the transposed Cholesky factor): whitened residuals are S r."""
    return jnp.linalg.cholesky(Wt).T


def _powers(Phi, Phi_inv, N: int, a: int):
    """Phi^{i-a} for i = 0 .. N."""
    d = Phi.shape[0]
    out = [None] * (N + 1)
    out[a] = jnp.eye(d, dtype=Phi.dtype)
    for i in range(a + 1, N + 1):
        out[i] = Phi @ out[i - 1]
    for i in range(a - 1, -1, -1):
        out[i] = Phi_inv @ out[i + 1]
    return out


class WeightedMHE(Estimator):
    """Weighted proximal MHE of horizon N for an LTI model ``Discrete(Phi, Phi_inv, W)`` (module docstring).

    ``meas_weight`` (p, p), ``arrival_weight`` (d, d), ``proc_weight`` (d, d) or None (hard model), ``gamma``
    the proximal scale; ``lower``/``upper`` (d,) box on every window state (``inf`` for none), ``A_c`` (r, d)
    and ``b_c`` (r,) affine constraints A_c z_i <= b_c on every window state; ``box_iters`` active-set
    iterations for either. ``N`` and the anchor ``a`` are static. Output: x_j (``Ahead`` hands out Phi x_j + W u_{j-1}, as for CPX). ``prior``:
    "smoothed" or "filtered" (see the module docstring); ``h(x)`` replaces ``C`` by a nonlinear output map
    (static, compared by identity); ``window_sqrt`` weighs the hard-model window residual as a whole (SCPX).
    Constructors for the usual cases: ``from_noise`` (Gaussian weights) and ``scpx``.
    """

    model: Discrete = eqx.field(converter=lambda m: Discrete(*(jnp.asarray(a, jnp.result_type(float)) for a in m)))
    C: Optional[jax.Array]
    meas_weight: jax.Array = param()
    arrival_weight: jax.Array = param()
    proc_weight: Optional[jax.Array]
    gamma: jax.Array = param()
    xhat0: jax.Array = param()
    lower: jax.Array = param()
    upper: jax.Array = param()
    N: int = eqx.field(static=True)
    anchor: int = eqx.field(static=True)
    A_c: Optional[jax.Array]
    b_c: Optional[jax.Array]
    box: bool = eqx.field(static=True)
    box_rows: tuple = eqx.field(static=True)  # the coordinates with a finite bound, fixed at construction
    box_iters: Optional[int] = eqx.field(static=True)
    prior: str = eqx.field(static=True)
    h: Optional[Callable] = eqx.field(static=True)
    window_sqrt: Optional[jax.Array]

    def __init__(self, model, C, meas_weight, arrival_weight, gamma=1.0, proc_weight=None, N: int = 2,
                 anchor: int = 0, xhat0=None, lower=None, upper=None, box_iters: Optional[int] = None,
                 prior: str = "smoothed", h: Optional[Callable] = None,
                 window_sqrt=None, A_c=None, b_c=None):
        d = validation.wmhe_args(self, model, C, meas_weight, arrival_weight, proc_weight, gamma, xhat0, N, anchor, prior)
        self.prior = prior
        if (C is None) == (h is None):
            raise ValueError("give exactly one of C (linear output map) and h (nonlinear output map)")
        self.C = None if C is None else jnp.asarray(C, jnp.result_type(float))
        self.h = h
        if window_sqrt is not None and proc_weight is not None:
            raise ValueError("window_sqrt is for the hard-model form (proc_weight=None)")
        self.window_sqrt = None if window_sqrt is None else jnp.asarray(window_sqrt, jnp.result_type(float))
        self.model, self.meas_weight, self.arrival_weight = model, meas_weight, arrival_weight
        self.proc_weight = None if proc_weight is None else jnp.asarray(proc_weight, jnp.result_type(float))
        self.gamma = gamma
        self.xhat0 = jnp.zeros(d) if xhat0 is None else xhat0
        self.lower = jnp.full(d, -jnp.inf) if lower is None else lower
        self.upper = jnp.full(d, jnp.inf) if upper is None else upper
        self.box = lower is not None or upper is not None
        self.box_rows = validation.bounded_coordinates(self.lower, self.upper) if self.box else ()
        if (A_c is None) != (b_c is None):
            raise ValueError("give both A_c and b_c (affine constraints A_c z <= b_c) or neither")
        fl = jnp.result_type(float)
        self.A_c = None if A_c is None else jnp.atleast_2d(jnp.asarray(A_c, fl))
        self.b_c = None if b_c is None else jnp.atleast_1d(jnp.asarray(b_c, fl))
        if A_c is not None and (self.A_c.shape[1] != d or self.b_c.shape != (self.A_c.shape[0],)):
            raise ValueError(f"A_c must be (r, {d}) and b_c (r,), got {self.A_c.shape} and {self.b_c.shape}")
        self.N, self.anchor, self.box_iters = N, anchor, box_iters

    __check_init__ = validation.check_weighted_mhe
    io_sizes = validation.weighted_mhe_sizes

    @classmethod
    def from_noise(cls, model: Discrete, C, Q, R, N: int, arrival_cov=None, **kw) -> "WeightedMHE":
        """The MHE of the Gaussian model: Wv = R^{-1}, Ww = Q^{-1}, Wa = P^{-1} with P = ``arrival_cov`` or the
        stationary a-priori covariance of the Kalman filter (the filtering DARE), gamma = 1. With ``h=...`` in
        ``kw``, C is the output Jacobian at the operating point, used for that DARE only."""
        from jaxdip.control.riccati import dare

        Phi = jnp.asarray(model[0])
        C = jnp.asarray(C, Phi.dtype)
        if arrival_cov is None:
            arrival_cov = dare(Phi.T, C.T, jnp.asarray(Q, Phi.dtype), jnp.asarray(R, Phi.dtype))
        inv = lambda M: jnp.linalg.inv(jnp.asarray(M, Phi.dtype))
        kw.setdefault("prior", "filtered")
        C_map = None if kw.get("h") is not None else C
        return cls(model, C_map, inv(R), inv(arrival_cov), 1.0, proc_weight=inv(Q), N=N, **kw)

    @classmethod
    def scpx(cls, model: Discrete, C, gamma, keep: int, **kw) -> "WeightedMHE":
        """SCPX (``CPX(..., keep=p)``) as a weighted MHE: the hard-model centred window (N = 2, a = 1) with
        the window weight P = Ug_p Ug_p^T, the projector onto the ``keep`` leading left singular vectors of
        G = [C Phi^{-1}; C; C Phi]. Its square root Ug_p^T is ``window_sqrt``: 1/2 ||Ug_p^T (G z - q)||^2 has the
        proximal point (1.26) of the thesis (the components of z outside V_p keep the prior)."""
        from jaxdip.estimators.cpx import centered_matrix
        from jaxdip.estimators.linearized import lti_step
        from jaxdip.estimators.proximal import svd_factor

        m = Discrete(*(jnp.asarray(a, jnp.result_type(float)) for a in model))
        C = jnp.asarray(C, m.Phi.dtype)
        Ug = svd_factor(centered_matrix(lti_step(m.Phi, m.Phi_inv, m.W), C)).Ug
        d, p = m.Phi.shape[0], C.shape[0]
        return cls(m, C, jnp.eye(p), jnp.eye(d), gamma, N=2, anchor=1, window_sqrt=Ug[:, :keep].T, **kw)

    # ---- the stacked problem --------------------------------------------------------------------------------

    @property
    def _dims(self):
        d, p, m = self.model.Phi.shape[0], self.meas_weight.shape[0], self.model.W.shape[1]
        return d, p, m

    def _output_matrices(self, Cs):
        return [self.C] * (self.N + 1) if Cs is None else [Cs[i] for i in range(self.N + 1)]

    def stacked_matrix(self, Cs=None) -> jax.Array:
        """A of min ||A X - b||: rows (arrival, measurements i = 0..N, process i = 0..N-1). ``Cs`` (N + 1, p, d):
        per-sample output matrices (the linearised h), else C."""
        d, p, _ = self._dims
        Cs = self._output_matrices(Cs)
        N, a = self.N, self.anchor
        Phi = self.model.Phi
        Sa = _sqrt_weight(self.arrival_weight) * (1.0 / jnp.sqrt(jnp.asarray(self.gamma, Phi.dtype)))
        Sv = _sqrt_weight(self.meas_weight)
        if self.proc_weight is None:
            Ms = _powers(Phi, self.model.Phi_inv, N, a)
            G = jnp.concatenate([Sv @ (Ci @ M) for Ci, M in zip(Cs, Ms)], axis=0)
            return jnp.concatenate([Sa, G if self.window_sqrt is None else self.window_sqrt @ G], axis=0)
        return window_matrix(Sa, Sv, _sqrt_weight(self.proc_weight), Cs, [Phi] * N, a)

    def _input_response(self, ubuf) -> list:
        """s_i, i = 0 .. N: the hard-model window's response to the known inputs with z_a = 0."""
        d, _, _ = self._dims
        N, a = self.N, self.anchor
        Phi, Phi_inv, W = self.model
        s = [None] * (N + 1)
        s[a] = jnp.zeros(d, Phi.dtype)
        for i in range(a + 1, N + 1):
            s[i] = Phi @ s[i - 1] + W @ ubuf[i - 1]
        for i in range(a - 1, -1, -1):
            s[i] = Phi_inv @ (s[i + 1] - W @ ubuf[i])
        return s

    def stacked_vector(self, xbar, ybuf, ubuf, Cs=None) -> jax.Array:
        d, p, _ = self._dims
        Cs = self._output_matrices(Cs)
        N = self.N
        Phi, _, W = self.model
        Sa = _sqrt_weight(self.arrival_weight) * (1.0 / jnp.sqrt(jnp.asarray(self.gamma, Phi.dtype)))
        Sv = _sqrt_weight(self.meas_weight)
        if self.proc_weight is None:
            s = self._input_response(ubuf)
            q = jnp.concatenate([Sv @ (ybuf[i] - Cs[i] @ s[i]) for i in range(N + 1)])
            return jnp.concatenate([Sa @ xbar, q if self.window_sqrt is None else self.window_sqrt @ q])
        return window_vector(Sa, Sv, xbar, ybuf, ubuf @ (_sqrt_weight(self.proc_weight) @ W).T)

    # ---- constraints --------------------------------------------------------------------------------------

    @property
    def constrained(self) -> bool:
        return self.box or self.A_c is not None

    def _state_rows(self):
        """(E, lo, hi): the constraints on one window state, lo <= E z <= hi (box rows first, then A_c)."""
        d, _, _ = self._dims
        dt = self.model.Phi.dtype
        rows = []
        if self.box:
            i = np.asarray(self.box_rows, dtype=int)
            rows.append((jnp.eye(d, dtype=dt)[i], self.lower[i], self.upper[i]))
        if self.A_c is not None:
            rows.append((self.A_c, jnp.full(self.b_c.shape, -jnp.inf, dt), self.b_c))
        return tuple(jnp.concatenate([r[j] for r in rows]) for j in range(3))

    def constraint_matrix(self):
        """(G, lo, hi): the window constraints in the unknown X as lo <= G X + c <= hi, rows ordered by window
        state i = 0 .. N (c from ``constraint_offset``)."""
        E, lo, hi = self._state_rows()
        N = self.N
        if self.proc_weight is not None:
            G = jnp.kron(jnp.eye(N + 1, dtype=E.dtype), E)
        else:
            G = jnp.concatenate([E @ M for M in _powers(self.model.Phi, self.model.Phi_inv, N, self.anchor)])
        return G, jnp.tile(lo, N + 1), jnp.tile(hi, N + 1)

    def constraint_offset(self, ubuf) -> jax.Array:
        """c of lo <= G X + c <= hi: zero for the full form, E s_i (the input response) for the hard model."""
        E, _, _ = self._state_rows()
        if self.proc_weight is not None:
            return jnp.zeros(E.shape[0] * (self.N + 1), E.dtype)
        return jnp.concatenate([E @ si for si in self._input_response(ubuf)])

    def _constraint_factor(self, R):
        """K = H^{-1} G^T and M = G H^{-1} G^T from the triangular factor R of H = R^T R."""
        G, _, _ = self.constraint_matrix()
        V = jsl.solve_triangular(R, G.T, trans="T", lower=False)  # R^{-T} G^T
        return jsl.solve_triangular(R, V, lower=False), V.T @ V

    def constrained_solve(self, R, X_u, KM, c):
        """The proximal step under the window constraints (``active_set.dual_active_set``): returns (X, KKT
        residual). ``KM``: (H^{-1} G^T, G H^{-1} G^T) from ``_constraint_factor(R)``."""
        G, lo, hi = self.constraint_matrix()
        iters = 2 * G.shape[0] + 2 if self.box_iters is None else self.box_iters
        return dual_active_set(G, lo, hi, *KM, R, X_u, c, iters)

    # ---- the engine protocol -------------------------------------------------------------------------------

    def init(self, key, x0):
        d, p, m = self._dims
        x = jnp.asarray(self.xhat0, dtype=dtype_of(x0))
        if self.h is None:
            Qm, R = jnp.linalg.qr(self.stacked_matrix(), mode="reduced")
            # the unconstrained estimate is linear in b: X = R^{-1} Q^T b, one matrix-vector product a step
            # (the batched triangular solve per step cost ~10x more under vmap on a CPU)
            factor = (jsl.solve_triangular(R, Qm.T, lower=False),)
            if self.constrained:
                factor += (R, self._constraint_factor(R))
        else:  # the stacked matrix changes with the linearisation point: factorised at every step
            factor = ()
        return WMHEState(factor, x, jnp.zeros((self.N + 1, p), x.dtype), jnp.zeros((self.N, m), x.dtype), x,
                         jnp.zeros((self.N + 1, d), x.dtype), x)

    def step(self, state: WMHEState, y, u_prev, key, k):
        d, p, m = self._dims
        N, a = self.N, self.anchor
        Phi, _, W = self.model
        u_prev = jnp.reshape(jnp.asarray(u_prev, state.xcur.dtype), (m,))
        ybuf = jnp.concatenate([state.ybuf[1:], jnp.reshape(y, (1, p))])
        ubuf = jnp.concatenate([state.ubuf[1:], u_prev[None]])
        x_model = jnp.where(k == 0, state.xcur, Phi @ state.xcur + W @ u_prev)  # xhat_{j|j-1}
        x_chain = jnp.where(k == 0, state.xchain, Phi @ state.xchain + W @ u_prev)
        pbuf = jnp.concatenate([state.pbuf[1:], x_chain[None]])
        xprior = state.xbar if self.prior == "smoothed" else pbuf[a]
        if self.h is None:
            X = state.factor[0] @ self.stacked_vector(xprior, ybuf, ubuf)
            if self.constrained:
                R, KM = state.factor[1:]
        else:
            # linearise h along the prior propagated through the window: y_i ~ h(zb_i) + H_i (z_i - zb_i)
            zb = [None] * (N + 1)
            zb[a] = xprior
            for i in range(a + 1, N + 1):
                zb[i] = Phi @ zb[i - 1] + W @ ubuf[i - 1]
            for i in range(a - 1, -1, -1):
                zb[i] = self.model.Phi_inv @ (zb[i + 1] - W @ ubuf[i])
            zb = jnp.stack(zb)
            Hs = jax.vmap(jax.jacfwd(self.h))(zb)
            y_lin = ybuf - jax.vmap(self.h)(zb) + jnp.einsum("ipd,id->ip", Hs, zb)
            Qm, R = jnp.linalg.qr(self.stacked_matrix(Hs), mode="reduced")
            X = jsl.solve_triangular(R, Qm.T @ self.stacked_vector(xprior, y_lin, ubuf, Hs), lower=False)
            if self.constrained:
                KM = self._constraint_factor(R)
        violation = jnp.zeros((), X.dtype)
        X_free = X
        if self.constrained:
            X, violation = self.constrained_solve(R, X, KM, self.constraint_offset(ubuf))

        def last_and_anchor(X):
            if self.proc_weight is not None:
                return X[N * d:], X[a * d:(a + 1) * d]
            z = X
            for i in range(a, N):
                z = Phi @ z + W @ ubuf[i]
            return z, X

        z_N, z_a = last_and_anchor(X)
        z_free = last_and_anchor(X_free)[0]
        full = k >= N
        xcur = jnp.where(full, z_N, x_model)
        xchain = jnp.where(full, z_free, x_chain)
        # the anchor prior: from the solution, or (warm-up) propagated once its time index k - N + a is >= 0
        xbar = jnp.where(full, Phi @ z_a + W @ ubuf[a],
                         jnp.where(k - N + a >= 0, Phi @ state.xbar + W @ ubuf[a], state.xbar))
        violation = jnp.where(full, violation, 0.0)
        if self.proc_weight is not None:
            window = X.reshape(N + 1, d)
        else:  # the hard model: z_i = Phi^{i-a} z_a + s_i
            Ms = _powers(Phi, self.model.Phi_inv, N, a)
            window = jnp.stack([M @ X + si for M, si in zip(Ms, self._input_response(ubuf))])
        aux = WMHEAux(xcur, Phi @ xcur + W @ u_prev, violation, jnp.where(full, window, 0.0))
        return WMHEState(state.factor, xbar, ybuf, ubuf, xcur, pbuf, xchain), xcur, aux
