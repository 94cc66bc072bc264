"""Linear model predictive control as an engine controller: box limits on the inputs, soft box limits on
chosen states, horizon N, terminal cost from the DARE, a warm-started QP per period, and gradients of anything
downstream (a closed-loop cost) with respect to its weights by implicit differentiation of the QP
(``jaxdip.control.qp``).

At each period, with dx = xhat - x_ref and U = [u_0 - u_ref, ..., u_{N-1} - u_ref]:

    min  sum_{k=1}^{N-1} dx_k^T Q dx_k + dx_N^T P dx_N + sum_{k=0}^{N-1} du_k^T R du_k + w |s|^2
    s.t. dx_{k+1} = A dx_k + B du_k,  u_min <= u_k <= u_max,
         x_min - s_k <= x_k[i] <= x_max + s_k  for the constrained states i, k = 1..N,

P the stabilising solution of the DARE for (A, B, Q, R), so without active limits the first input is the
discrete LQR's -K dx (a test checks this). The condensed form eliminates the states (X = Sx dx_0 + Su U); the
slacks s (one per constrained state and step, shared by its two sides) make the state limits soft, so the QP is
always feasible; a slack needs no sign constraint (a negative one only tightens both sides, so the optimum never
takes one). Everything that depends only on the weights (P, the condensed H and G, their factors) is formed in
``step`` from the fields: under ``vmap`` over seeds it is not batched, so it is computed once per period for the
whole batch, and ``grad`` reaches Q, R and the limits through it.

The controller's state is the QP's working set, shifted one step (the plan's step k + 1 is the next period's
step k), which warm-starts the next solve; ``aux`` reports the QP's ``status`` (``QPCode``) and its iteration
count. On a nonlinear plant the model is the linearisation at the plant's equilibrium, discretised exactly under
the zero-order hold (``LinearMPC.for_plant``).
"""

from __future__ import annotations

from typing import Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.control.qp import solve_qp
from jaxdip.control.riccati import dare
from jaxdip.engine import checks
from jaxdip.engine.roles import Controller, Plant, linearize, param
from jaxdip.sim.discretize import zoh


from jaxdip._public import public_dir

__all__ = ["LinearMPC", "condense"]
__dir__ = public_dir(globals())


def condense(A, B, N: int) -> tuple[jax.Array, jax.Array]:
    """(Sx, Su) with [x_1; ...; x_N] = Sx x_0 + Su [u_0; ...; u_{N-1}] for x_{k+1} = A x_k + B u_k."""
    n, m = B.shape

    def power(P, _):
        return A @ P, P

    _, pows = jax.lax.scan(power, jnp.eye(n, dtype=A.dtype), None, length=N + 1)  # A^0 ... A^N
    Sx = pows[1:].reshape(N * n, n)
    i, j = np.arange(N)[:, None], np.arange(N)[None, :]
    blocks = jnp.where(jnp.asarray(i >= j)[..., None, None], (pows[:N] @ B)[np.maximum(i - j, 0)], 0.0)
    Su = blocks.transpose(0, 2, 1, 3).reshape(N * n, N * m)  # block (i, j) = A^(i-j) B for j <= i
    return Sx, Su


class LinearMPC(Controller):
    """Constrained linear MPC u = u_ref + du_0 of the QP in the module docstring.

    ``A, B``: the discrete model (n, n), (n, m); ``Q`` (n, n) PSD, ``R`` (m, m) PD: the stage weights;
    ``horizon`` (static): N; ``u_min, u_max``: input limits (scalars or (m,); +-inf for none); ``x_min, x_max``:
    state limits, (n,) with +-inf where a state is free (which states are constrained is fixed when the
    controller is made); ``slack_weight``: w, the price of violating a state limit; ``x_ref, u_ref``: the
    operating point; ``max_iter`` (static): the QP's iteration limit (default 2 x rows + 2)."""

    A: jax.Array = param()
    B: jax.Array = param()
    Q: jax.Array = param()
    R: jax.Array = param()
    u_min: jax.Array = param()
    u_max: jax.Array = param()
    x_min: jax.Array = param()  # limits of the constrained states only
    x_max: jax.Array = param()
    slack_weight: jax.Array = param()
    x_ref: jax.Array = param()
    u_ref: jax.Array = param()
    horizon: int = eqx.field(static=True)
    constrained: tuple = eqx.field(static=True)
    max_iter: Optional[int] = eqx.field(static=True)

    def __init__(self, A, B, Q, R, horizon: int, u_min=-np.inf, u_max=np.inf, x_min=None, x_max=None,
                 slack_weight=1e6, x_ref=None, u_ref=None, max_iter: Optional[int] = None):
        for name, v in (("A", A), ("B", B), ("Q", Q), ("R", R)):
            checks.check_real(self, name, v)
            checks.check_finite(self, name, v)
        n = checks.check_square(self, "A", A)
        checks.check_ndim(self, "B", B, (2,), "an (n, m) input matrix")
        m = checks.shape_of(B)[1]
        checks.check_shape(self, "B", B, (n, m), f"(A is {n} x {n})")
        checks.check_square(self, "Q", Q, n, f"(A is {n} x {n})")
        checks.check_square(self, "R", R, m, f"(B is {n} x {m})")
        checks.check_psd(self, "Q", Q)
        checks.check_psd(self, "R", R, definite=True)
        checks.check_int(self, "horizon", horizon, 1)
        if max_iter is not None:
            checks.check_int(self, "max_iter", max_iter, 1)
        checks.check_positive(self, "slack_weight", slack_weight)
        u_min = jnp.broadcast_to(jnp.asarray(u_min, dtype=jnp.float64), (m,))
        u_max = jnp.broadcast_to(jnp.asarray(u_max, dtype=jnp.float64), (m,))
        checks.check_limits(self, "u_min", u_min, "u_max", u_max)
        x_min = np.full(n, -np.inf) if x_min is None else np.asarray(x_min, dtype=float)
        x_max = np.full(n, np.inf) if x_max is None else np.asarray(x_max, dtype=float)
        for name, v in (("x_min", x_min), ("x_max", x_max), ("x_ref", x_ref)):
            if v is not None:
                checks.check_shape(self, name, v, (n,), f"(A is {n} x {n}; +-inf where a state is free)")
        checks.check_limits(self, "x_min", x_min, "x_max", x_max)
        self.constrained = tuple(int(i) for i in np.flatnonzero(np.isfinite(x_min) | np.isfinite(x_max)))
        sel = list(self.constrained)
        self.A, self.B, self.Q, self.R = A, B, Q, R
        self.u_min, self.u_max = u_min, u_max
        self.x_min, self.x_max = x_min[sel], x_max[sel]
        self.slack_weight = slack_weight
        self.x_ref = jnp.zeros(n) if x_ref is None else x_ref
        self.u_ref = jnp.zeros(m) if u_ref is None else jnp.broadcast_to(jnp.asarray(u_ref, dtype=float), (m,))
        self.horizon, self.max_iter = int(horizon), max_iter

    @classmethod
    def for_plant(cls, plant: Plant, dt: float, Q, R, horizon: int, **kw) -> "LinearMPC":
        """MPC on the linearisation of ``plant`` at its equilibrium (zero input), discretised exactly under the
        zero-order hold with period ``dt``; keywords as ``LinearMPC``."""
        if not isinstance(plant, Plant):
            raise checks.ArgumentTypeError(f"LinearMPC.for_plant: plant must be a jaxdip Plant, got "
                                           f"{type(plant).__name__}")
        Ac, Bc = linearize(plant)
        if plant.continuous:
            d = zoh(Ac, Bc, dt)
            Ac, Bc = d.Phi, d.W
        R = jnp.atleast_2d(jnp.asarray(R, dtype=jnp.float64))
        return cls(Ac, Bc, Q, R, horizon, x_ref=plant.equilibrium(), **kw)

    def io_sizes(self) -> dict:
        why = f"B is {checks.fmt_shape(self.B.shape)}"
        return {"in": (self.B.shape[0], why), "out": (self.B.shape[1], why)}

    @property
    def _rows(self) -> tuple[int, int]:
        # rows of the QP per plan step: the inputs, then each constrained state's lower and upper side
        return self.B.shape[1], len(self.constrained)

    def init(self, key, x0):
        m, ns = self._rows
        r = self.horizon * (m + 2 * ns)
        return jnp.zeros(r, bool), jnp.ones(r)

    def qp(self, xhat):
        """(H, q, G, lo, hi) of the period's QP at the estimate ``xhat``, unknowns [du_0..du_{N-1}, slacks]."""
        N, (m, ns) = self.horizon, self._rows
        n = self.A.shape[0]
        P = dare(self.A, self.B, self.Q, self.R)
        Sx, Su = condense(self.A, self.B, N)
        Qbar = jnp.kron(jnp.eye(N), self.Q).at[(N - 1) * n:, (N - 1) * n:].set(P)
        Hu = Su.T @ Qbar @ Su + jnp.kron(jnp.eye(N), self.R)
        dx0 = xhat - self.x_ref
        qu = Su.T @ (Qbar @ (Sx @ dx0))
        Iu = jnp.eye(N * m)
        lo_u = jnp.tile(self.u_min - self.u_ref, N)
        hi_u = jnp.tile(self.u_max - self.u_ref, N)
        if ns == 0:
            return 0.5 * (Hu + Hu.T), qu, Iu, lo_u, hi_u
        sel = (np.arange(N)[:, None] * n + np.asarray(self.constrained)[None, :]).ravel()
        Gx, x_free = Su[sel], (Sx @ dx0)[sel] + jnp.tile(self.x_ref[np.asarray(self.constrained)], N)
        Is = jnp.eye(N * ns)
        H = jax.scipy.linalg.block_diag(Hu, self.slack_weight * Is)
        G = jnp.concatenate([jnp.concatenate([Iu, jnp.zeros((N * m, N * ns))], 1),
                             jnp.concatenate([Gx, Is], 1), jnp.concatenate([Gx, -Is], 1)])
        inf = jnp.full(N * ns, jnp.inf)
        lo = jnp.concatenate([lo_u, jnp.tile(self.x_min, N) - x_free, -inf])
        hi = jnp.concatenate([hi_u, inf, jnp.tile(self.x_max, N) - x_free])
        q = jnp.concatenate([qu, jnp.zeros(N * ns)])
        return 0.5 * (H + H.T), q, G, lo, hi

    def solve(self, xhat, warm=None):
        """The period's QP solution (``jaxdip.control.qp.QPSolution``) at ``xhat``."""
        return solve_qp(*self.qp(xhat), warm=warm, max_iter=self.max_iter)

    def _shift(self, v):
        # the plan's step k + 1 becomes step k; the last step repeats
        N, (m, ns) = self.horizon, self._rows
        parts, start = [], 0
        for width in (m, ns, ns):
            blk = v[start:start + N * width].reshape(N, width)
            parts.append(jnp.concatenate([blk[1:], blk[-1:]]).ravel())
            start += N * width
        return jnp.concatenate(parts)

    def step(self, state, xhat, key, k):
        sol = self.solve(xhat, warm=state)
        m = self.B.shape[1]
        u = self.u_ref + sol.z[:m]
        return (self._shift(sol.active), self._shift(sol.side)), u, {"status": sol.status,
                                                                    "iterations": sol.iterations}

