"""A dense, strictly convex QP solver in JAX: min 1/2 z^T H z + q^T z subject to lo <= G z <= hi (rows with an
infinite bound are one-sided), warm-startable, with a status code, batched by ``vmap`` and differentiable.

The iterations are the dual active-set method (Goldfarb and Idnani) of the constrained MHE
(``jaxdip.estimators.active_set.dual_step``), here driven by a ``while_loop`` that stops as soon as no row is
violated, so a warm start that already holds the right working set costs no iteration (the loop's test reads the
rows' violations without a factorisation). Why that solver and not
an ADMM / OSQP-style splitting: each iteration is an exact solve, so the answer meets the KKT conditions to
rounding (a tolerance of 1e-7 against an interior-point solver needs no polishing step), and the iteration count
does not depend on the conditioning of H, which the condensed MPC makes poor (an unstable plant's powers A^k);
ADMM would need a penalty tuned to that conditioning and hundreds of iterations for the same accuracy.

Warm start: the working set and sides of a previous solution (an MPC's, shifted by one period). The method needs
a dual-feasible start, so the multipliers of that working set are solved for and the start is kept only if they
all have the right sign; otherwise the solve starts cold (never a wrong answer, at worst a cold start).

Gradients are implicit: the solve itself sees no derivatives (``stop_gradient``), and a ``custom_jvp`` returns
its z with the tangent of the KKT system at the solution's working set W,
H dz + G_W^T dmu = -dH z - dq - dG^T mu,  G_W dz = db_W - dG_W z,
solved through the Schur complement G_W H^{-1} G_W^T. Forward and reverse mode both work (the tangent is linear),
and no iteration of the solver is unrolled. Where a row is weakly active (on its bound with a zero multiplier)
the solution is not differentiable and this returns the derivative with that row held.

Status (``QPCode``): SOLVED (no row violated beyond a relative 1e-11 and the multipliers of the working set
of the right sign), MAX_ITERATIONS (the limit reached first), INFEASIBLE (a row with lo > hi, rows of the final
working set that still miss their bounds, or multipliers grown past 1e12 times the problem's scale: in a dual
method primal infeasibility shows as dual divergence).
"""

from __future__ import annotations

import enum
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.engine import checks
from jaxdip.estimators.active_set import dual_consts, dual_finished, dual_step
from jaxdip.estimators.kalman import guarded_cho_factor


from jaxdip._public import public_dir

__all__ = ["QPCode", "QPSolution", "solve_qp"]
__dir__ = public_dir(globals())

_DIVERGED = 1e12  # |mu| over the problem's scale that reads as an infeasible problem


class QPCode(enum.IntEnum):
    """``QPSolution.status``."""

    SOLVED = 0
    MAX_ITERATIONS = 1
    INFEASIBLE = 2


class QPSolution(NamedTuple):
    """z: the minimiser (differentiable in H, q, G, lo, hi); mu: the signed multipliers (> 0 at an upper bound,
    < 0 at a lower one, 0 off the working set); active, side: the working set and its sides (+1 upper, -1
    lower), what a later solve takes as ``warm``; status: a ``QPCode``; iterations: active-set iterations run;
    residual: the largest row infeasibility left."""

    z: jax.Array
    mu: jax.Array
    active: jax.Array
    side: jax.Array
    status: jax.Array
    iterations: jax.Array
    residual: jax.Array


def solve_qp(H, q, G, lo, hi, *, warm: Optional[tuple] = None, max_iter: Optional[int] = None) -> QPSolution:
    """Solve min 1/2 z^T H z + q^T z subject to lo <= G z <= hi; H (n, n) symmetric positive definite, q (n,),
    G (r, n), lo and hi (r,) with -inf / +inf where a row has no bound on that side.

    ``warm``: ``(active, side)`` of an earlier solution of a problem of the same size (used only where it is
    dual feasible, see the module docstring); ``max_iter`` (static, default 2 r + 2): the most active-set
    iterations. Works under jit and vmap; z is differentiable (implicit, at the working set)."""
    n = checks.check_square("solve_qp", "H", H)
    checks.check_shape("solve_qp", "q", q, (n,), f"(H is {n} x {n})")
    checks.check_ndim("solve_qp", "G", G, (2,), "an (r, n) matrix of constraint rows")
    r = checks.shape_of(G)[0]
    checks.check_shape("solve_qp", "G", G, (r, n), f"(H is {n} x {n})")
    for name, v in (("lo", lo), ("hi", hi)):
        checks.check_shape("solve_qp", name, v, (r,), f"(G has {r} rows)")
    if max_iter is None:
        max_iter = 2 * r + 2
    checks.check_int("solve_qp", "max_iter", max_iter, 1)
    if warm is not None:
        if len(warm) != 2:
            checks.fail("solve_qp", "warm must be (active, side) of an earlier solution")
        checks.check_shape("solve_qp", "warm[0]", warm[0], (r,), f"(G has {r} rows)")
        checks.check_shape("solve_qp", "warm[1]", warm[1], (r,), f"(G has {r} rows)")
    H, q, G, lo, hi = (jnp.asarray(v, dtype=jnp.float64) for v in (H, q, G, lo, hi))
    sg = jax.lax.stop_gradient
    z, mu, act, side, status, iters, gap = _solve(sg(H), sg(q), sg(G), sg(lo), sg(hi), warm, max_iter)
    return QPSolution(_at_working_set(H, q, G, lo, hi, z, mu, act, side), mu, act, side, status, iters, gap)


def _masked(M, act):
    # M on the working set, its diagonal elsewhere: a nonsingular system whose solution is 0 off the set
    dM = jnp.where(jnp.diag(M) > 0, jnp.diag(M), 1.0)
    return jnp.where(act[:, None] & act[None, :], M, 0.0) + jnp.diag(jnp.where(act, 0.0, dM))


def _targets(lo, hi, act, side):
    fin = lambda v: jnp.where(jnp.isfinite(v), v, 0.0)
    return jnp.where(act, jnp.where(side > 0, fin(hi), fin(lo)), 0.0)


def _solve(H, q, G, lo, hi, warm, max_iter):
    cf = jsl.cho_factor(H, lower=True)
    z_u = -jsl.cho_solve(cf, q)
    K = jsl.cho_solve(cf, G.T)
    M = G @ K
    s_u = G @ z_u
    consts = dual_consts(M, lo, hi, s_u)
    r = s_u.shape[0]
    cold = (jnp.zeros(r), jnp.zeros(r, bool), jnp.ones(r), jnp.array(-1))
    if warm is None:
        start = cold
    else:
        act0 = jnp.asarray(warm[0], bool)
        side0 = jnp.where(jnp.asarray(warm[1]) > 0, 1.0, -1.0)
        rhs = jnp.where(act0, s_u - _targets(lo, hi, act0, side0), 0.0)
        mu0 = jnp.where(act0, jsl.cho_solve(guarded_cho_factor(_masked(M, act0)), rhs), 0.0)
        ok = jnp.all(jnp.where(act0, side0 * mu0 >= 0, True)) & jnp.all(jnp.isfinite(mu0))
        start = jax.tree_util.tree_map(lambda w, c: jnp.where(ok, w, c), (mu0, act0, side0, jnp.array(-1)), cold)

    def cond(c):
        k, inner = c
        return (k < max_iter) & ~dual_finished(consts, inner)

    def body(c):
        k, inner = c
        return k + 1, dual_step(consts, inner)[0]

    k, (mu, act, side, pend) = jax.lax.while_loop(cond, body, (jnp.array(0), start))
    done = dual_finished(consts, (mu, act, side, pend))
    z = z_u - K @ mu
    s = G @ z
    gap = jnp.max(jnp.maximum(jnp.maximum(s - hi, lo - s), 0.0), initial=0.0)
    scale = jnp.maximum(jnp.max(jnp.abs(q), initial=0.0) + jnp.max(jnp.abs(consts[-1]), initial=0.0), 1.0)
    diverged = ~jnp.all(jnp.isfinite(mu)) | (jnp.max(jnp.abs(mu), initial=0.0) > _DIVERGED * scale)
    # a finished working set whose rows still miss their bounds has met a dependence it cannot satisfy
    stuck = done & (gap > 1e-9 * jnp.maximum(jnp.max(consts[-1], initial=0.0), 1.0))
    infeasible = jnp.any(lo > hi) | diverged | stuck
    status = jnp.where(infeasible, QPCode.INFEASIBLE, jnp.where(done, QPCode.SOLVED, QPCode.MAX_ITERATIONS))
    return z, mu, act, side, status.astype(jnp.int32), k, gap


@jax.custom_jvp
def _at_working_set(H, q, G, lo, hi, z, mu, act, side):
    """z (computed by the solver); its tangent is that of the KKT system at the working set (module doc)."""
    return z


@_at_working_set.defjvp
def _at_working_set_jvp(primals, tangents):
    H, q, G, lo, hi, z, mu, act, side = primals
    dH, dq, dG, dlo, dhi = tangents[:5]
    cf = jsl.cho_factor(H, lower=True)
    K = jsl.cho_solve(cf, G.T)
    r1 = -dH @ z - dq - dG.T @ mu
    Hr1 = jsl.cho_solve(cf, r1)
    # where a bound is infinite its tangent is not used (the mask comes from the primal: a select on a
    # tangent's value would not be linear)
    db = jnp.where(side > 0, jnp.where(jnp.isfinite(hi), dhi, 0.0), jnp.where(jnp.isfinite(lo), dlo, 0.0))
    rhs = jnp.where(act, G @ Hr1 - (db - dG @ z), 0.0)
    dmu = jnp.where(act, jsl.cho_solve(guarded_cho_factor(_masked(G @ K, act)), rhs), 0.0)
    return z, Hr1 - K @ dmu
