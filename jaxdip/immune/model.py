"""The infection model (A1)–(A6) of thesis ch. 4 and its closed forms.

One infected cell sits at the origin of R^d. It dies after tau_eta ~ Exp(eta) (A1) and releases, all at once,
Z ~ Poisson(beta tau_eta) virions (A2). Virion j decays after tau_delta ~ Exp(delta) (A4), enters a cell after
tau_gamma ~ Exp(gamma) (A5) and moves as a Brownian motion from the origin with heat kernel
p(t, x) = (4 pi D t)^(-d/2) exp(-|x|^2 / (4 D t)) (A6, diffusion coefficient D: dp/dt = D Laplacian p, so each
coordinate has variance 2 D t). It infects iff it enters before it decays and the cell it enters is not
protected at that moment: X_j = 1{tau_gamma <= tau_delta, (tau_gamma, W(tau_gamma)) not in A}.

Time is measured from the release (the infected cell's death): (4.2) integrates p(0, t, 0, x) against the entry
time's density from t = 0, which holds only with that origin (see docs/immune.md). Then (4.1)–(4.5):

    E[Z] = beta / eta,   R0 = beta gamma / (eta (gamma + delta)),
    E[I] = R0 - int_A g,   g(t, x) = (beta gamma / eta) exp(-(gamma + delta) t) p(t, x).

Two changes of variable carry the rest of the package. With k = gamma + delta,
s = 1 - exp(-k t) and w = P(d/2, |x|^2 / (4 D t)) (P the regularised lower incomplete gamma function, so w is
the fraction of the heat kernel's mass inside radius |x|), the measure g dx dt becomes R0 ds dw(.)
on [0, 1)^2 for radial sets: the g-mass of a radial set is R0 times its area in (s, w). And u = |x| / sqrt(4 D t)
is the similarity variable in which the heat kernel does not spread.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import gammaln


def as_float(x):
    """Numbers in modules are stored as float64 arrays: traced under jit (one compilation serves every value,
    and ``jax.grad`` reaches them), never baked in as constants."""
    return jnp.asarray(x, dtype=jnp.float64)


class Infection(eqx.Module):
    """Parameters of (A1)–(A6); rates per unit time, ``diffusion`` in length^2 per unit time."""

    eta: jax.Array = eqx.field(converter=as_float, default=1.0 / 12.0)
    beta: jax.Array = eqx.field(converter=as_float, default=2.5)
    gamma: jax.Array = eqx.field(converter=as_float, default=0.1)
    delta: jax.Array = eqx.field(converter=as_float, default=0.9)
    diffusion: jax.Array = eqx.field(converter=as_float, default=36.0)
    dim: int = eqx.field(static=True, default=2)

    def __check_init__(self):
        if self.dim not in (1, 2, 3):
            raise ValueError(f"dim must be 1, 2 or 3, got {self.dim}")

    # ---- (4.1)–(4.5) --------------------------------------------------------------------------------------

    @property
    def k(self):
        """Rate at which a free virion stops being free (enters or decays)."""
        return self.gamma + self.delta

    @property
    def mean_burst(self):
        """E[Z] = beta / eta (A1)–(A2)."""
        return self.beta / self.eta

    @property
    def entry_prob(self):
        """P(tau_gamma <= tau_delta) = gamma / (gamma + delta): E[X_j] with no control."""
        return self.gamma / self.k

    @property
    def R0(self):
        """beta gamma / (eta (gamma + delta)), (4.3) with A empty."""
        return self.mean_burst * self.entry_prob

    @property
    def c(self):
        """The constant beta gamma / eta in front of g (4.5)."""
        return self.beta * self.gamma / self.eta

    def log_heat_kernel(self, t, rho):
        """log p(t, x) at |x| = rho (A6)."""
        four_dt = 4.0 * self.diffusion * t
        return -0.5 * self.dim * jnp.log(math.pi * four_dt) - rho**2 / four_dt

    def log_g(self, t, rho):
        """log g(t, x) of (4.5) at |x| = rho: the density, over time and space, of infections the control can
        prevent."""
        return jnp.log(self.c) - self.k * t + self.log_heat_kernel(t, rho)

    def log_virion_density(self, t, rho):
        """Expected density of free virions at (t, x): E[Z] e^{-k t} p(t, x) = g / gamma.

        This is what a cell can sense (§4.5): thresholds on it are thresholds on g, scaled by gamma."""
        return self.log_g(t, rho) - jnp.log(self.gamma)

    def times_where_log_g(self, rho, level, iters: int = 120):
        """Both times t > 0 with log g(t, rho) = level (NaN where there is none), for arrays rho >= 0, level.

        d/dt log g(t, rho) = -k - d / (2 t) + rho^2 / (4 D t^2) has one positive zero
        t* = (sqrt(d^2 D^2 + 4 D k rho^2) - d D) / (4 D k), so log g rises on (0, t*] and falls after (t* = 0 for
        rho = 0): at most one root on each side, each bracketed (log g -> -inf as t -> 0 for rho > 0, +inf for
        rho = 0, and -inf as t -> inf) and found by bisection in log t."""
        D, k, d = self.diffusion, self.k, self.dim
        rho, level = jnp.broadcast_arrays(jnp.asarray(rho, jnp.float64), jnp.asarray(level, jnp.float64))
        t_star = (jnp.sqrt((d * D) ** 2 + 4.0 * D * k * rho**2) - d * D) / (4.0 * D * k)
        lt_star = jnp.log(jnp.maximum(t_star, 1e-300))
        lt_min, lt_max = math.log(1e-300), math.log(1e6)

        def phi(lt):
            return self.log_g(jnp.exp(lt), rho) - level

        def solve(lo, hi, rising):
            def body(_, c):
                lo, hi = c
                mid = 0.5 * (lo + hi)
                up = (phi(mid) < 0) == rising  # the root lies above mid
                return jnp.where(up, mid, lo), jnp.where(up, hi, mid)

            lo, hi = jax.lax.fori_loop(0, iters, body, (lo, hi))
            return 0.5 * (lo + hi)

        peak = phi(lt_star)
        has = (peak >= 0) | (rho == 0)
        left = solve(jnp.full_like(rho, lt_min), lt_star, True)
        right = solve(jnp.where(rho == 0, lt_min, lt_star), jnp.full_like(rho, lt_max), False)
        t_left = jnp.where(has & (rho > 0), jnp.exp(left), jnp.nan)
        t_right = jnp.where(has, jnp.exp(right), jnp.nan)
        return t_left, t_right

    # ---- the (s, u, w) coordinates ------------------------------------------------------------------------

    def t_of_s(self, s):
        return -jnp.log1p(-s) / self.k

    def s_of_t(self, t):
        return -jnp.expm1(-self.k * t)

    def rho_of_u(self, t, u):
        return u * jnp.sqrt(4.0 * self.diffusion * t)

    def u_of_rho(self, t, rho):
        return rho / jnp.sqrt(4.0 * self.diffusion * t)

    def mass_fraction(self, u):
        """w = P(d/2, u^2): the heat kernel's mass inside radius u sqrt(4 D t)."""
        return mass_fraction(u, self.dim)


def mass_fraction(u, dim: int):
    """P(d/2, u^2) in closed form for d = 1, 2, 3 (faster than the general incomplete gamma, and smooth)."""
    x = u * u
    if dim == 1:
        return jax.lax.erf(u)
    if dim == 2:
        return -jnp.expm1(-x)
    return jax.lax.erf(u) - 2.0 * u * jnp.exp(-x) / math.sqrt(math.pi)


def ball_volume(rho, dim: int):
    """Lebesgue measure of the d-ball of radius rho."""
    return math.pi ** (dim / 2) / math.gamma(dim / 2 + 1) * rho**dim


def sphere_area(dim: int) -> float:
    """Surface area S_d of the unit sphere in R^d (2, 2 pi, 4 pi)."""
    return 2.0 * math.pi ** (dim / 2) / math.gamma(dim / 2)


def lower_gamma_series(a: float, x, n_terms: int):
    """P(a + j, x) for j = 0 .. n_terms - 1 by the downward recurrence P(a + j + 1, x) = P(a + j, x) - x^(a+j)
    e^(-x) / Gamma(a + j + 1), starting from the closed form at a = d/2 (a in {1/2, 1, 3/2})."""
    dim = int(round(2 * a))
    p0 = mass_fraction(jnp.sqrt(x), dim)
    j = jnp.arange(n_terms - 1, dtype=jnp.float64)
    x_ = jnp.maximum(x, 1e-300)[..., None]
    log_terms = (a + j) * jnp.log(x_) - x_ - gammaln(a + j + 1.0)
    cum = jnp.cumsum(jnp.exp(log_terms), axis=-1)
    out = jnp.concatenate([p0[..., None], p0[..., None] - cum], axis=-1)
    return jnp.clip(out, 0.0, 1.0)


# ---- the branching process beyond one generation ----------------------------------------------------------


def offspring_pgf(s, mean):
    """Generating function of one cell's infection progeny I under a fixed per-cell control.

    Given tau_eta, Z is Poisson(beta tau_eta) and each virion infects independently with probability p = E[X_j]
    (A3), so I | tau_eta ~ Poisson(beta p tau_eta); mixing over tau_eta ~ Exp(eta) makes I geometric on
    {0, 1, ...} with mean R = beta p / eta = E[I]: G(s) = 1 / (1 + R (1 - s)).
    """
    return 1.0 / (1.0 + mean * (1.0 - s))


def extinction_iterates(mean, generations: int):
    """q_g = P(no infected cell in generation g) = G(q_{g-1}), q_0 = 0, for g = 1 .. generations."""

    def step(q, _):
        q = offspring_pgf(q, mean)
        return q, q

    return jax.lax.scan(step, jnp.zeros_like(jnp.asarray(mean, dtype=jnp.float64)), None, length=generations)[1]


def extinction_probability(mean, iterations: int = 200_000, tol: float = 1e-13):
    """Smallest fixed point of G in [0, 1], by iterating q <- G(q) from 0 (monotone convergence).

    The closed form for geometric offspring is min(1, 1 / R); the iteration is what a general offspring law
    would need, and converges slowly (like 1 / g) at R = 1.
    """

    def cond(c):
        i, q, dq = c
        return (i < iterations) & (dq > tol)

    def body(c):
        i, q, _ = c
        qn = offspring_pgf(q, mean)
        return i + 1, qn, jnp.abs(qn - q)

    return jax.lax.while_loop(cond, body, (0, jnp.asarray(0.0), jnp.asarray(1.0)))[1]
