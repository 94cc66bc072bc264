"""Controls that compete with the level set at the same target V = int_A g (Theorem 4.4.1's check).

- The best ball over a time window: for each window [t0, t1) the radius that reaches V is found by bisection,
  the window is searched on a grid in (s0, s1) refined twice around its best cell, and the winner is re-solved
  with the bracketed quadrature so that it meets V as accurately as the level set does.
- Random perturbations of the level set: {log(g/h) - xi(s, w) >= log r} with xi a random smooth field
  (``controls.RandomTilt``) and r re-tuned so that the set again has g-mass V.
Both families contain only sets that differ from L_r_bar on a set of positive measure, so the theorem says each
costs strictly more.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip import program_cache
from jaxdip.immune import quadrature as Q
from jaxdip.immune.controls import BallWindow, LevelSet, RandomTilt
from jaxdip.immune.model import Infection


def _gl(n: int):
    x, w = np.polynomial.legendre.leggauss(n)
    return jnp.asarray(x), jnp.asarray(w)


def _ball_gh(model: Infection, cost, rho, s0, s1, n_gl: int):
    """(int g, int h) of the ball of radius rho over s in [s0, s1), Gauss–Legendre in s (search only)."""
    x, w = _gl(n_gl)
    s = 0.5 * (s1 - s0) * (x + 1.0) + s0
    t = model.t_of_s(s)
    m = model.mass_fraction(model.u_of_rho(t, rho))
    H = jax.vmap(lambda tt: cost.shell_mass(model, tt, 0.0, rho))(t)
    half = 0.5 * (s1 - s0)
    return model.R0 * half * jnp.sum(w * m), half * jnp.sum(w * H / (model.k * (1.0 - s)))


def _radius_for(model, cost, V, s0, s1, n_gl, iters=60):
    """Radius of the ball over [s0, s1) with g-mass V (inf when the window cannot hold V)."""
    feasible = model.R0 * (s1 - s0) > V * (1.0 + 1e-9)
    t1 = model.t_of_s(s1)
    log_hi = jnp.log(12.0 * jnp.sqrt(4.0 * model.diffusion * t1) + 1.0)

    def fun(lr):  # nonincreasing in log radius
        return -_ball_gh(model, cost, jnp.exp(lr), s0, s1, n_gl)[0]

    lr = Q.bisect_largest(fun, -V, jnp.asarray(-12.0), log_hi, iters)
    return jnp.where(feasible, jnp.exp(lr), jnp.inf)


@program_cache.jit
def _grid_costs(model, cost, V, s0, s1, n_gl):
    def one(a, b):
        rho = _radius_for(model, cost, V, a, b, n_gl)
        h = _ball_gh(model, cost, jnp.where(jnp.isfinite(rho), rho, 1.0), a, b, n_gl)[1]
        return jnp.where(jnp.isfinite(rho) & (b > a), h, jnp.inf), rho

    return jax.vmap(one)(s0, s1)


def best_ball_window(model: Infection, cost, V: float, *, grid: int = 40, refine: int = 2, n_gl: int = 64,
                     n_quad: int = 4096):
    """(BallWindow, masses): the ball over a window with g-mass V and the least int h found by the search."""
    S_HI = 0.999
    lo0, hi0, lo1, hi1 = 0.0, S_HI, 0.0, S_HI
    best = None
    for _ in range(refine + 1):
        a = np.linspace(lo0, hi0, grid)
        b = np.linspace(lo1, hi1, grid)
        A, B = np.meshgrid(a, b, indexing="ij")
        h, rho = _grid_costs(model, cost, jnp.asarray(V, float), jnp.asarray(A.ravel()), jnp.asarray(B.ravel()),
                             n_gl)
        h = np.asarray(h)
        i = int(np.argmin(h))
        best = (A.ravel()[i], B.ravel()[i])
        da, db = 2 * (hi0 - lo0) / (grid - 1), 2 * (hi1 - lo1) / (grid - 1)
        lo0, hi0 = max(0.0, best[0] - da), min(S_HI, best[0] + da)
        lo1, hi1 = max(0.0, best[1] - db), min(S_HI, best[1] + db)
    t0, t1 = (float(model.t_of_s(jnp.asarray(v))) for v in best)
    # the winner's radius again, with the bracketed quadrature the level set is measured by
    ball = _solve_ball(model, cost, V, t0, t1, n_quad)
    return ball, Q.masses(model, ball, cost, n_quad)


def _solve_ball(model, cost, V, t0, t1, n_quad):
    t0, t1 = jnp.asarray(t0, float), jnp.asarray(t1, float)

    def fun(lr):  # nonincreasing in log radius
        return -Q.masses(model, BallWindow(jnp.asarray(math.exp(lr)), t0, t1), cost, n_quad).g

    hi = math.log(12.0 * math.sqrt(4.0 * float(model.diffusion) * float(t1)) + 1.0)
    return BallWindow(jnp.asarray(math.exp(Q.bisect_host(fun, -float(V), -12.0, hi))), t0, t1)


def retune(model: Infection, control: LevelSet, cost, V, n_quad: int = 4096, width: float = 8.0) -> LevelSet:
    """The same (possibly tilted) level set with log r moved so that its g-mass is V (bisection within
    +- width of the current log r)."""

    def with_r(lr):
        return eqx.tree_at(lambda c: c.log_r, control, jnp.asarray(lr, float))

    x = float(control.log_r)
    lr = Q.bisect_host(lambda v: Q.masses(model, with_r(v), cost, n_quad).g, float(V), x - width, x + width)
    return with_r(lr)


def perturbations(model: Infection, cost, log_r_bar, V: float, key, count: int, *, modes: int = 3,
                  eps: float = 0.5, n_quad: int = 4096):
    """``count`` random perturbations of L_r_bar, each re-tuned to g-mass V: list of (LevelSet, masses)."""
    out = []
    for i in range(count):
        tilt = RandomTilt.draw(jax.random.fold_in(key, i), modes, eps)
        c = retune(model, LevelSet(cost=cost, log_r=jnp.asarray(log_r_bar), tilt=tilt), cost, V, n_quad)
        out.append((c, Q.masses(model, c, cost, n_quad)))
    return out
