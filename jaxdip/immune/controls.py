"""Protection controls A ⊂ [0, inf) x R^d as sets over (time since release, position).

Every control answers ``protected(model, t, x, key_cell, key_virion)`` for the Monte Carlo (x of shape (d,);
the keys drive stochastic responses: ``key_cell`` is shared by all virions of one infected cell, so a random
pattern of responding cells is one draw per infected cell, ``key_virion`` is the virion's own). A virion's
infection depends on the control only through (tau_gamma, W(tau_gamma)), so no path is ever discretised.

Controls the quadrature can integrate also give ``profile(model, t, cost) -> (m, H)``: m = the heat kernel's
mass inside A(t) (so int_A g = int c e^{-kt} m(t) dt) and H = int_{A(t)} h dx; and ``breakpoints(model)``, the
times where A(t) jumps, which the quadrature puts on panel edges. Radial controls give ``shells(model, t)``:
shells a_i <= |x| < b_i with weights (1 for protected, q in (0, 1) where a stochastic response protects with
probability q), from which ``profile`` follows.
"""

from __future__ import annotations

import math
from typing import Any, Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.immune.costs import RadialCost
from jaxdip.immune.levelset import U_MAX, grid_intervals, piecewise_monotone_intervals
from jaxdip.immune.model import as_float, Infection, ball_volume, lower_gamma_series, mass_fraction


def no_breaks() -> jax.Array:
    """No breakpoints: an empty time array (made when asked, not at import, which must not start JAX's backend
    before a caller has set XLA's flags)."""
    return jnp.zeros((0,))


def shells_profile(model: Infection, cost, t, a, b, weight):
    """(m, H) of a union of weighted shells [a_i, b_i) at time t."""
    w = lambda r: mass_fraction(model.u_of_rho(t, r), model.dim)  # noqa: E731
    m = jnp.sum(weight * (w(b) - w(a)))
    H = jnp.sum(weight * cost.shell_mass(model, t, a, b))
    return m, H


class Radial(eqx.Module):
    """Base for controls given by shells: profile from shells."""

    def profile(self, model, t, cost):
        a, b, wt = self.shells(model, t)
        return shells_profile(model, cost, t, a, b, wt)

    def breakpoints(self, model):
        return no_breaks()


class NoControl(Radial):
    def protected(self, model, t, x, key_cell, key_virion):
        return jnp.zeros((), bool)

    def shells(self, model, t):
        z = jnp.zeros((1,))
        return z, z, z


class BallWindow(Radial):
    """Protect the ball |x| <= radius during t0 <= t < t1."""

    radius: jax.Array = eqx.field(converter=as_float)
    t0: jax.Array = eqx.field(converter=as_float)
    t1: jax.Array = eqx.field(converter=as_float)

    def _on(self, t):
        return (t >= self.t0) & (t < self.t1)

    def protected(self, model, t, x, key_cell, key_virion):
        return self._on(t) & (jnp.sum(x * x) <= self.radius**2)

    def shells(self, model, t):
        b = jnp.where(self._on(t), self.radius, 0.0)
        return jnp.zeros((1,)), b[None], jnp.ones((1,))

    def breakpoints(self, model):
        return jnp.stack([jnp.asarray(self.t0, float), jnp.asarray(self.t1, float)])


class RandomTilt(eqx.Module):
    """A smooth random field xi(s, w) = eps sum_{k,l} coef_kl cos(pi k s) cos(pi l w) on the (s, w) square,
    used to perturb a level set: {log(g/h) - xi >= log r} (coefficients drawn N(0, 1) / (1 + k + l)^2)."""

    coef: jax.Array
    eps: jax.Array = eqx.field(converter=as_float)

    @staticmethod
    def draw(key, modes: int, eps: float) -> "RandomTilt":
        k = jnp.arange(modes)
        damp = 1.0 / (1.0 + k[:, None] + k[None, :]) ** 2
        return RandomTilt(jax.random.normal(key, (modes, modes)) * damp, eps)

    def __call__(self, s, w):
        k = jnp.arange(self.coef.shape[0])
        cs = jnp.cos(math.pi * k * s[..., None])
        cw = jnp.cos(math.pi * k * w[..., None])
        return self.eps * jnp.einsum("...k,kl,...l->...", cs, self.coef, cw)


class LevelSet(Radial):
    """The level set {g/h >= r} of (4.6) for a cost h, optionally tilted by a field xi(s, w) (a perturbation) and
    optionally (``stochastic``) with a random response on the tie band |log(g/h) - log r| <= tie_tol: protected
    with probability tie_prob there, independently per virion (a continuum of independently responding points;
    see ``jaxdip.immune.autonomous`` for cells). That is the non-unique case of Theorem 4.4.1.

    Untilted, its shells are exact (``levelset.piecewise_monotone_intervals``: one shell per piece between the
    cost's jumps, no component missed) and its ``breakpoints`` are the times where the set changes shape, so
    the quadrature's segments end on every kink of its integrands. Tilted sets (competitors only) use the grid
    (``n_grid``, ``max_intervals``) and have no breakpoints."""

    cost: eqx.Module
    log_r: jax.Array = eqx.field(converter=as_float)
    tilt: RandomTilt | None = None
    tie_tol: jax.Array = eqx.field(converter=as_float, default=0.0)
    tie_prob: jax.Array = eqx.field(converter=as_float, default=1.0)
    stochastic: bool = eqx.field(static=True, default=False)
    n_grid: int = eqx.field(static=True, default=129)
    max_intervals: int = eqx.field(static=True, default=4)

    def _f(self, model, t, rho, w):
        f = self.cost.log_ratio(t, rho, model.log_g(t, rho)) - self.log_r
        if self.tilt is not None:
            f = f - self.tilt(model.s_of_t(t), w)
        return f

    def protected(self, model, t, x, key_cell, key_virion):
        rho = jnp.sqrt(jnp.sum(x * x))
        f = self._f(model, t, rho, mass_fraction(model.u_of_rho(t, rho), model.dim))
        if not self.stochastic:
            return f >= 0
        u = jax.random.uniform(jax.random.fold_in(key_virion, 17))
        return (f > self.tie_tol) | ((f >= -self.tie_tol) & (u < self.tie_prob))

    def _intervals(self, model, t, offset):
        if self.tilt is None:
            jumps = jnp.clip(model.u_of_rho(t, self.cost.jump_radii()), 0.0, U_MAX)
            edges = jnp.concatenate([jnp.zeros(1), jnp.sort(jumps), jnp.full(1, U_MAX)])

            def f(u, piece):
                rho = model.rho_of_u(t, u)
                return self.cost.log_ratio_on(t, rho, model.log_g(t, rho), piece) - self.log_r - offset

            a, b = piecewise_monotone_intervals(f, edges)
        else:
            def f(u):
                rho = model.rho_of_u(t, u)
                return self._f(model, t, rho, mass_fraction(u, model.dim)) - offset

            a, b, over = grid_intervals(f, n_grid=self.n_grid, max_intervals=self.max_intervals)
            # more shells than slots: NaN, so that every integral over this set says so instead of being wrong
            a, b = jnp.where(over, jnp.nan, a), jnp.where(over, jnp.nan, b)
        return model.rho_of_u(t, a), model.rho_of_u(t, b)

    def shells(self, model, t):
        if not self.stochastic:
            a, b = self._intervals(model, t, 0.0)
            return a, b, jnp.ones_like(a)
        # 1 on the strict set {f > tol}, q on the band: q * 1{f >= -tol} + (1 - q) * 1{f > tol}
        a1, b1 = self._intervals(model, t, self.tie_tol)
        a2, b2 = self._intervals(model, t, -self.tie_tol)
        q = jnp.asarray(self.tie_prob, float)
        wt = jnp.concatenate([jnp.full_like(a1, 1.0 - q), jnp.full_like(a2, q)])
        return jnp.concatenate([a1, a2]), jnp.concatenate([b1, b2]), wt

    def breakpoints(self, model):
        """Times where the set changes shape (a boundary meets a jump of the cost, or the set vanishes): the
        kinks of m(s) and of the cost integrand, which the quadrature puts on segment ends (NaN: none)."""
        if self.tilt is not None:
            return no_breaks()
        offsets = jnp.stack([self.tie_tol, -self.tie_tol]) if self.stochastic else jnp.zeros(1)
        rho, level = jax.vmap(lambda o: self.cost.event_levels(jax.lax.stop_gradient(self.log_r) + o))(offsets)
        t_left, t_right = model.times_where_log_g(rho, level)
        return jnp.concatenate([t_left.ravel(), t_right.ravel()])


class OffsetBallWindow(eqx.Module):
    """Protect the ball |x - center| <= radius during t0 <= t < t1: a set that is not radial about the infected
    cell. Its heat-kernel mass is a noncentral chi-square probability, summed as a Poisson mixture of
    incomplete gamma functions: P(|W_t - c| <= rho) = sum_j Pois(j; lam) P(d/2 + j, rho^2 / (4 D t)) with
    lam = |c|^2 / (4 D t); ``n_terms`` must exceed lam by many standard deviations (checked by the caller
    through ``max_lambda``)."""

    center: jax.Array
    radius: jax.Array = eqx.field(converter=as_float)
    t0: jax.Array = eqx.field(converter=as_float)
    t1: jax.Array = eqx.field(converter=as_float)
    n_terms: int = eqx.field(static=True, default=256)

    def _on(self, t):
        return (t >= self.t0) & (t < self.t1)

    def protected(self, model, t, x, key_cell, key_virion):
        d = x - self.center
        return self._on(t) & (jnp.sum(d * d) <= self.radius**2)

    def max_lambda(self, model):
        return jnp.sum(self.center**2) / (4.0 * model.diffusion * self.t0)

    def profile(self, model, t, cost):
        if not isinstance(cost, RadialCost):
            raise NotImplementedError("OffsetBallWindow integrates only the uniform cost")
        four_dt = 4.0 * model.diffusion * jnp.maximum(t, 1e-300)
        lam = jnp.sum(self.center**2) / four_dt
        j = jnp.arange(self.n_terms, dtype=jnp.float64)
        log_pois = j * jnp.log(jnp.maximum(lam, 1e-300)) - lam - jax.scipy.special.gammaln(j + 1.0)
        P = lower_gamma_series(model.dim / 2, self.radius**2 / four_dt, self.n_terms)
        m = jnp.sum(jnp.exp(log_pois) * P)
        on = self._on(t)
        H = jnp.where(cost.is_uniform, ball_volume(self.radius, model.dim), jnp.nan)  # other costs: not integrated
        return jnp.where(on, m, 0.0), jnp.where(on, H, 0.0)

    def breakpoints(self, model):
        return jnp.stack([jnp.asarray(self.t0, float), jnp.asarray(self.t1, float)])


class Indicator(eqx.Module):
    """Any measurable set, given by its indicator ``fn(t, x, params) -> bool`` (Monte Carlo only: no profile).

    ``params`` (any pytree of arrays) holds the set's numbers, so they are traced and one compiled program serves
    every value; ``fn`` is part of the compiled program's identity, so pass a module-level function."""

    fn: Callable = eqx.field(static=True)
    params: Any = None

    def protected(self, model, t, x, key_cell, key_virion):
        return jnp.asarray(self.fn(t, x, self.params), bool)


class Window(Radial):
    """A radial control restricted to the times t0 <= t < t1 (t1 may be inf)."""

    inner: eqx.Module
    t0: jax.Array = eqx.field(converter=as_float, default=0.0)
    t1: jax.Array = eqx.field(converter=as_float, default=float("inf"))

    def _on(self, t):
        return (t >= self.t0) & (t < self.t1)

    def protected(self, model, t, x, key_cell, key_virion):
        return self._on(t) & self.inner.protected(model, t, x, key_cell, key_virion)

    def shells(self, model, t):
        a, b, wt = self.inner.shells(model, t)
        return a, b, jnp.where(self._on(t), wt, 0.0)

    def breakpoints(self, model):
        own = jnp.stack([jnp.asarray(self.t0, float), jnp.minimum(jnp.asarray(self.t1, float), 1e300)])
        return jnp.concatenate([self.inner.breakpoints(model), own])


@eqx.filter_jit
def breakpoints(model: Infection, control) -> jax.Array:
    """``control.breakpoints(model)`` as one compiled program, for calls from the host: run op by op, a level
    set's search for the times where it changes shape traces its loops anew at every call (0.8 s each, against
    a millisecond compiled), and the numbers are the same."""
    return control.breakpoints(model)
