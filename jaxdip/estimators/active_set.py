"""A dual active-set method for the small strictly convex QPs of the constrained proximal MHE
(``jaxdip.estimators.weighted_mhe``).

The constrained proximal step is the strictly convex QP min 1/2 X^T H X - g^T X subject to rows
lo <= G X + c <= hi, H = A^T A = R^T R, solved through its multipliers by a dual
active-set method (Goldfarb and Idnani 1983): with K = H^{-1} G^T and M = G H^{-1} G^T (fixed for an LTI model:
formed in ``init`` from the QR factor), a working set W of rows held at their bounds gives
M_WW mu_W = G_W X_u + c_W - bound_W and X = X_u - K mu, X_u the unconstrained minimiser. Each iteration adds the
most violated row; if a multiplier of the working set would change sign, the step stops where it reaches zero and
that row leaves. Why this and not projected gradient, ADMM or a dual gradient step inside the proximal step:
each iteration is an exact solve, so the answer satisfies the KKT conditions to rounding as soon as the working
set is right, and the iteration count does not depend on the conditioning of H, which is poor here (Ww = Q^{-1}
is large for a precise model); the others would need many iterations and a step or penalty tuned to that
conditioning, and projecting onto a polyhedron is itself a QP. Why one row at a time and not the all-at-once
primal-dual active-set update (every violated row in, every wrong-sign multiplier out) that suffices for a box:
with affine rows that update can pick more rows than the window has freedom for, and it cycled to an infeasible
point on the hard-model test problem (3 unknowns, 25 rows, some repeated). Dependent rows are handled by the
guarded factor of M (a long finite step along the dependence; the ratio test then drops the blocking row). The
cost is a Cholesky of the masked M per iteration, one iteration per row that becomes active. A fixed number of
iterations (``box_iters``, default 2 x rows + 2) keeps it a static program under jit/vmap (and reverse-mode
differentiable); ``aux.violation`` reports the KKT residual left (row infeasibility and wrong-sign multipliers).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.estimators.kalman import guarded_cho_factor


from jaxdip._public import public_dir

__all__ = ["dual_active_set", "dual_consts", "dual_step", "dual_finished"]
__dir__ = public_dir(globals())


def dual_active_set(G, lo, hi, K, M, R, X_u, c, iters: int):
    """Dual active-set iterations (Goldfarb and Idnani) for min 1/2 X^T H X - g^T X subject to
    lo <= G X + c <= hi, from the unconstrained minimiser X_u = H^{-1} g (module docstring), H = R^T R,
    K = H^{-1} G^T, M = G H^{-1} G^T; ``iters`` (static) iterations. Returns (X, KKT residual)."""
    s_u = G @ X_u + c
    n_rows = s_u.shape[0]
    consts = dual_consts(M, lo, hi, s_u)
    init = (jnp.zeros_like(s_u), jnp.zeros(n_rows, bool), jnp.ones_like(s_u), jnp.array(-1))
    mu, act, side, _ = jax.lax.fori_loop(0, iters, lambda _, carry: dual_step(consts, carry)[0], init)
    X = X_u - K @ mu
    s = G @ X + c
    # KKT residual: feasibility of every row, and multipliers of the right sign on the working set
    # (complementarity holds by construction: mu = 0 off it, its rows sit on their bounds)
    gap = jnp.max(jnp.maximum(jnp.maximum(s - hi, lo - s), 0.0), initial=0.0)
    g = R.T @ (R @ X_u)
    wrong = jnp.max(jnp.where(act, jnp.maximum(-side * mu, 0.0), 0.0), initial=0.0)
    return X, jnp.maximum(gap, wrong * jnp.max(jnp.abs(G)) / jnp.maximum(jnp.max(jnp.abs(g)), 1.0))


def dual_consts(M, lo, hi, s_u) -> tuple:
    """What every iteration of ``dual_step`` reads: (s_u, M, its guarded diagonal, lo, hi, the scale of the
    feasibility tolerance); s_u = G X_u + c, the rows at the unconstrained minimiser."""
    dM = jnp.diag(M)
    dM = jnp.where(dM > 0, dM, 1.0)
    bound_scale = jnp.abs(_fin(lo)) + jnp.abs(_fin(hi)) + jnp.abs(s_u)
    return s_u, M, dM, lo, hi, bound_scale


def _fin(v):
    return jnp.where(jnp.isfinite(v), v, 0.0)


def dual_step(consts: tuple, carry: tuple) -> tuple:
    """One dual active-set iteration: ``carry`` = (signed multipliers (> 0 at an upper bound), working set,
    sides, pending row or -1). Returns (carry, idle); idle: no row was violated and none pending, so the carry
    is the solution and is returned unchanged."""
    s_u, M, dM, lo, hi, bound_scale = consts
    fin = _fin
    idx = jnp.arange(s_u.shape[0])
    mu, act, side, pend = carry
    over, viol, cand = _violations(consts, mu, act)
    # the most violated row in the H^{-1} metric (its distance to the bound over the row's norm)
    j_new = jnp.argmax(jnp.where(cand, viol / jnp.sqrt(dM), -jnp.inf))
    pend = jnp.where(pend >= 0, pend, jnp.where(jnp.any(cand), j_new, -1))
    idle = pend < 0
    is_p = (idx == pend) & ~idle
    side2 = jnp.where(is_p, jnp.where(over[jnp.maximum(pend, 0)] > 0, 1.0, -1.0), side)
    A2 = act | is_p
    target = jnp.where(A2, jnp.where(side2 > 0, fin(hi), fin(lo)), 0.0)
    rhs = jnp.where(A2, s_u - target, 0.0)
    Mm = jnp.where(A2[:, None] & A2[None, :], M, 0.0) + jnp.diag(jnp.where(A2, 0.0, dM))
    # a pending row dependent on the working set makes Mm singular: the guarded factor then gives a long
    # finite step along the dependence, and the ratio test below drops the row that blocks it
    mu_full = jnp.where(A2, jsl.cho_solve(guarded_cho_factor(Mm), rhs), 0.0)
    wrong = act & (side * mu_full < 0)
    ratio = jnp.where(wrong, mu / jnp.where(wrong, mu - mu_full, 1.0), jnp.inf)
    k_drop = jnp.argmin(ratio)
    partial = jnp.any(wrong)
    t = jnp.where(partial, ratio[k_drop], 1.0)
    mu_next = mu + t * (mu_full - mu)
    act_next = jnp.where(partial, act & (idx != k_drop), A2)
    mu_next = jnp.where(act_next | (is_p & partial), mu_next, 0.0)
    pend_next = jnp.where(partial, pend, -1)
    keep = lambda old, new: jnp.where(idle, old, new)
    return (keep(mu, mu_next), keep(act, act_next), keep(side, side2), keep(pend, pend_next)), idle


def _violations(consts, mu, act):
    # rows over their upper bound, the violation of each row, and the violated rows outside the working set
    s_u, M, _, lo, hi, bound_scale = consts
    s = s_u - M @ mu  # G X + c at X = X_u - K mu
    over, under = s - hi, lo - s
    viol = jnp.maximum(over, under)
    tol = 1e-11 * (bound_scale + jnp.abs(M @ mu)) + jnp.finfo(s.dtype).tiny
    return over, viol, ~act & (viol > tol)


def dual_finished(consts: tuple, carry: tuple) -> jax.Array:
    """Whether ``dual_step`` would be idle on ``carry`` (no row pending or violated), without its factorisation."""
    mu, act, _, pend = carry
    return (pend < 0) & ~jnp.any(_violations(consts, mu, act)[2])
