"""Costs h(t, x) > 0 of protecting a point of time x space, for problem (P), all radial in x.

A cost gives ``log_ratio(t, rho, log_g)``, the log of g/h that the level sets L_r of (4.6) threshold, and
``shell_mass(model, t, a, b)``, the integral of h over the shell a <= |x| < b at time t (closed form), which the
quadrature needs for the objective of (P). ``log_g`` is passed in because one cost here depends on g itself.

For the exact level-set boundaries (``levelset.piecewise_monotone_intervals``) a cost also names the radii
where h jumps (``jump_radii``, a fixed number per class) and gives its log ratio on each piece between them
(``log_ratio_on(t, rho, log_g, piece)``), nonincreasing in |x| on every piece. For the quadrature's segments it
gives ``event_levels(log_r)``: pairs (rho, L) such that the level set's shape changes (a boundary reaches a jump
or the set vanishes) exactly where log g(t, rho) = L, an equation in t that ``model.times_where_log_g`` solves.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.immune.model import as_float, Infection, ball_volume, mass_fraction, sphere_area


def _vol(model: Infection, a, b):
    return ball_volume(b, model.dim) - ball_volume(a, model.dim)


class RadialCost(eqx.Module):
    """h = (1 + (|x| / scale)^2) (1 + extra 1{inner <= |x| < outer}): one family with closed-form shell integrals
    that holds the uniform cost (scale = inf, extra = 0), a cost growing with distance, and a costly shell.
    (One class for all three, so one compiled quadrature serves them all.)"""

    inv_scale2: jax.Array = eqx.field(converter=as_float, default=0.0)  # 1 / scale^2
    inner: jax.Array = eqx.field(converter=as_float, default=0.0)
    outer: jax.Array = eqx.field(converter=as_float, default=0.0)
    extra: jax.Array = eqx.field(converter=as_float, default=0.0)

    def _in(self, rho):
        return (rho >= self.inner) & (rho < self.outer)

    def log_h(self, t, rho, log_g):
        return jnp.log1p(rho**2 * self.inv_scale2) + jnp.where(self._in(rho), jnp.log1p(self.extra), 0.0) + 0.0 * t

    def log_ratio(self, t, rho, log_g):
        return log_g - self.log_h(t, rho, log_g)

    def jump_radii(self):
        return jnp.stack([self.inner, self.outer])

    def log_ratio_on(self, t, rho, log_g, piece):
        """log(g/h) on piece 0 (|x| < inner), 1 (the shell) or 2 (|x| >= outer): log g - log(1 + |x|^2/l^2)
        - log(1 + extra) [piece 1], nonincreasing in |x| on each piece."""
        return log_g - jnp.log1p(rho**2 * self.inv_scale2) - jnp.where(piece == 1, jnp.log1p(self.extra), 0.0)

    def event_levels(self, log_r):
        """(rho, L): the set vanishes where log g(t, 0) = log r; a boundary reaches the shell's edge rho_e from
        either side where log g(t, rho_e) = log r + log h on that side."""
        e = jnp.log1p(self.extra)
        rho = jnp.stack([jnp.zeros(()), self.inner, self.inner, self.outer, self.outer])
        base = log_r + jnp.log1p(rho**2 * self.inv_scale2)
        return rho, base + jnp.stack([0.0, 0.0, e, e, 0.0])

    def _poly(self, model, a, b):
        d = model.dim
        return _vol(model, a, b) + self.inv_scale2 * sphere_area(d) / (d + 2) * (b ** (d + 2) - a ** (d + 2))

    def shell_mass(self, model, t, a, b):
        ca, cb = jnp.clip(a, self.inner, self.outer), jnp.clip(b, self.inner, self.outer)
        return self._poly(model, a, b) + self.extra * self._poly(model, ca, cb) + 0.0 * t

    @property
    def is_uniform(self):
        return (self.inv_scale2 == 0) & (self.extra == 0)


def Uniform() -> RadialCost:
    """h = 1: the objective of (P) is the space-time volume protected (§4.5's first case)."""
    return RadialCost()


def Distance(scale=10.0) -> RadialCost:
    """h = 1 + (|x| / scale)^2: protecting cells far from the infected cell costs more."""
    return RadialCost(inv_scale2=1.0 / jnp.asarray(scale, jnp.float64) ** 2)


def Shell(inner=6.0, outer=10.0, extra=4.0) -> RadialCost:
    """h = 1 + extra on the shell inner <= |x| < outer, 1 elsewhere: a costly region (e.g. a layer of cells
    whose antiviral state is harmful) that the optimal set avoids where it can."""
    return RadialCost(inner=inner, outer=outer, extra=extra)


class Flat(eqx.Module):
    """h = max(1, g / r_flat): g/h = min(g, r_flat) is flat (= r_flat) on the set {g >= r_flat}.

    A construction for the non-unique case of Theorem 4.4.1 / Corollary 4.4.2: F jumps at r_flat from
    F(r_flat) = int_{g >= r_flat} g to 0, so for any V below F(r_flat) the threshold is r_bar = r_flat, the level
    set L_r_bar over-shoots V, and every subset of it with g-mass V is optimal with cost V / r_flat.
    (The cost must depend on t to make g/h flat on a set of positive measure: e^{-kt} p(t, x) is analytic and
    not constant in t on any open set.) ``log_ratio`` is min(log g, log r_flat) computed exactly, so the flat
    set is exactly {log_ratio == log r_flat} in floating point.
    """

    log_r: jax.Array = eqx.field(converter=as_float, default=0.0)

    def log_h(self, t, rho, log_g):
        return jnp.maximum(0.0, log_g - self.log_r)

    def log_ratio(self, t, rho, log_g):
        return jnp.minimum(log_g, self.log_r)

    def jump_radii(self):
        return jnp.zeros((0,))

    def log_ratio_on(self, t, rho, log_g, piece):
        return jnp.minimum(log_g, self.log_r)

    def event_levels(self, log_r):
        """The set {min(g, r_f) >= r} vanishes where g(t, 0) = r (r <= r_f); h has a kink where the flat set
        itself vanishes, g(t, 0) = r_f."""
        return jnp.zeros(2), jnp.stack([jnp.minimum(log_r, self.log_r), self.log_r])

    def flat_radius(self, model, t):
        """Radius inside which g >= r_flat at time t (0 where nowhere)."""
        lhs = jnp.log(model.c) - model.k * t - 0.5 * model.dim * jnp.log(4.0 * math.pi * model.diffusion * t)
        return jnp.sqrt(4.0 * model.diffusion * t * jnp.maximum(lhs - self.log_r, 0.0))

    def shell_mass(self, model, t, a, b):
        rf = self.flat_radius(model, t)
        ia, ib = jnp.minimum(a, rf), jnp.minimum(b, rf)
        # inside rf: h = g / r_flat, whose shell integral is (c e^{-kt} / r_flat) times the heat-kernel mass
        w = lambda r: mass_fraction(model.u_of_rho(t, r), model.dim)  # noqa: E731
        inner = model.c * jnp.exp(-model.k * t - self.log_r) * (w(ib) - w(ia))
        return inner + _vol(model, jnp.maximum(a, rf), jnp.maximum(b, rf))
