"""Homogeneous model-based differentiators (HOMD) for the reaction-wheel pendulum (Aranovskiy et al., §III).

Signed power. ``spow(x, a)`` is ⌈x⌋^a = |x|^a sgn(x). Its derivative in x, a |x|^(a-1), is infinite at 0 for
a < 1 and its derivative in a, ln|x| |x|^a sgn(x), is 0 * (-inf) there; a naive ``jnp.abs(x)**a * jnp.sign(x)``
therefore gives NaN gradients whenever an error is exactly zero (the first sample, a quantised signal at rest).
``spow`` evaluates the power on a safe argument (1 where x = 0) and selects 0 there, and carries a custom JVP:
at x = 0 the a-derivative is 0 (its limit) and the x-derivative is 1 for a = 1 (so the linear case linearises
correctly), 0 for a > 1 and, where the true one is infinite (a < 1), 0 as a finite convention.

Pendulum observer (10) on x_p = [theta, theta'] with measurement y of theta:

    x̂_p1' = x̂_p2 - k_p1 ⌈x̂_p1 - y⌋^α_p
    x̂_p2' = -(k/J) I + a1 sin(y) - k_p2 ⌈x̂_p1 - y⌋^(2α_p - 1),      a1 = ml g / J.

The paper writes sin(theta) in the model term; the observer only has y, so the model term uses the measurement.
That is what makes the biased error dynamics (14) carry a1 cos(theta) d (sin(theta + d) - sin(theta) ≈ cos(theta) d),
and without bias it makes the error dynamics exactly (11):

    e_1' = e_2 - k_p1 ⌈e_1⌋^α_p,   e_2' = -k_p2 ⌈e_1⌋^(2α_p - 1),   e = x̂_p - x_p.

Wheel observer (12) on x_r = [theta_r, theta_r'] with measurement y_r of theta_r, model term from (3):

    x̂_r1' = x̂_r2 - k_r1 ⌈x̂_r1 - y_r⌋^α_r
    x̂_r2' = ((J + Jr) k / (J Jr)) I - a1 sin(y) - k_r2 ⌈x̂_r1 - y_r⌋^(2α_r - 1).

Proposition 1 (finite-time stability of (11)) needs α in (1/2, 1) and s^2 + k1 s + k2 Hurwitz; Table 2 uses
[k, k2, α] = [5, 12, 0.9] for both.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.estimators.continuous import SampledObserver
from jaxdip.plants import rwp


from jaxdip._public import public_dir

__all__ = ["spow", "HOMDGains", "gains", "differentiator_rhs", "error_rhs", "a1", "pendulum_accel",
           "wheel_current_gain", "wheel_accel", "rwp_homd_rhs", "observer_model", "HOMDObserver", "as_gains",
           "check_gains", "check_observer_model"]
__dir__ = public_dir(globals())


@jax.custom_jvp
def spow(x, a):
    """⌈x⌋^a = |x|^a sgn(x), with finite derivatives in x and a everywhere (see the module docstring)."""
    x, a = jnp.asarray(x), jnp.asarray(a)
    nz = x != 0
    safe = jnp.where(nz, jnp.abs(x), 1.0)
    return jnp.where(nz, jnp.sign(x) * safe**a, 0.0)


@spow.defjvp
def _spow_jvp(primals, tangents):
    x, a = (jnp.asarray(v) for v in primals)
    dx, da = (jnp.asarray(v) for v in tangents)
    nz = x != 0
    safe = jnp.where(nz, jnp.abs(x), 1.0)
    mag = safe**a
    out = jnp.where(nz, jnp.sign(x) * mag, 0.0)
    # d/dx: a |x|^(a-1); at x = 0 the limit is 1 for a = 1, 0 for a > 1 and +inf for a < 1, which we replace
    # by 0 (the value at 0 of the one-sided derivative of the odd extension's secant through the origin as
    # x -> 0 diverges; 0 keeps gradients finite and treats an exactly-zero error as locally flat).
    ddx = jnp.where(nz, a * mag / safe, jnp.where(a == 1, 1.0, 0.0))
    # d/da: ln|x| ⌈x⌋^a, whose limit at x = 0 is 0 for a > 0
    dda = jnp.where(nz, jnp.log(safe) * out, 0.0)
    return out, ddx * dx + dda * da


class HOMDGains(NamedTuple):
    """[k1, k2, α] of one differentiator: (10) uses [k_p1, k_p2, α_p], (12) [k_r1, k_r2, α_r]."""

    k1: jnp.ndarray
    k2: jnp.ndarray
    alpha: jnp.ndarray


def gains(k1=5.0, k2=12.0, alpha=0.9) -> HOMDGains:
    f = lambda v: jnp.asarray(v, dtype=jnp.float64)  # noqa: E731
    return HOMDGains(f(k1), f(k2), f(alpha))


def as_gains(owner, name: str, g) -> HOMDGains:
    """``g`` (HOMDGains, or a sequence (k1, k2, alpha)) as HOMDGains, checked by ``check_gains``."""
    if not isinstance(g, HOMDGains):
        if isinstance(g, (str, bytes)) or not hasattr(g, "__len__") or len(g) != 3:
            checks.fail(owner, f"{name} must be the three gains (k1, k2, alpha), got {g!r}")
        for f, v in zip(HOMDGains._fields, g):
            checks.check_real(owner, f"{name}.{f}", v)
        g = gains(*g)
    check_gains(owner, name, g)
    return g


def check_gains(owner, name: str, g) -> None:
    """Scalar gains with k1, k2 > 0 and alpha in (0.5, 1]: the exponent 2 alpha - 1 of (10)/(12) must be positive
    (below 0.5 the correction term is singular at zero error) and alpha = 1 is the linear differentiator."""
    if not isinstance(g, HOMDGains):
        raise checks.ArgumentTypeError(f"{checks.owner_name(owner)}: {name} must be HOMDGains (k1, k2, alpha), "
                                       f"got {type(g).__name__}")
    for f, v in zip(HOMDGains._fields, g):
        checks.check_ndim(owner, f"{name}.{f}", v, (0,), "a scalar")
    checks.check_positive(owner, f"{name}.k1", g.k1)
    checks.check_positive(owner, f"{name}.k2", g.k2)
    if checks.is_concrete(g.alpha) and not 0.5 < float(g.alpha) <= 1.0:
        checks.fail(owner, f"{name}.alpha must be in (0.5, 1], got {float(g.alpha):.6g}")


def check_observer_model(owner, model) -> None:
    """``model`` is an RWP (its constants are the observer's model terms a1, k/J, ...)."""
    if not isinstance(model, rwp.RWP):
        raise checks.ArgumentTypeError(f"{checks.owner_name(owner)}: model must be an RWP (the observer's model "
                                       f"of the plant), got {type(model).__name__}")


def differentiator_rhs(g: HOMDGains, xhat, y, accel):
    """Model-based homogeneous differentiator: d/dt [x̂1, x̂2] for measurement y and model acceleration."""
    e1 = xhat[0] - y
    return jnp.stack([xhat[1] - g.k1 * spow(e1, g.alpha), accel - g.k2 * spow(e1, 2.0 * g.alpha - 1.0)])


def error_rhs(g: HOMDGains, e):
    """The error dynamics (11) (and (13)): d/dt [e1, e2]."""
    return jnp.stack([e[1] - g.k1 * spow(e[0], g.alpha), -g.k2 * spow(e[0], 2.0 * g.alpha - 1.0)])


# ---- model terms of (2)-(3) -----------------------------------------------------------------------------


def a1(p: rwp.RWP):
    """a1 = ml g / J (the gravity coefficient of (2) and (14))."""
    return rwp.mass_moment(p) * p.g / rwp.inertia(p)


def pendulum_accel(p: rwp.RWP, I, theta):
    """(2): theta'' = -(k/J) I + a1 sin(theta)."""
    return -p.k / rwp.inertia(p) * I + a1(p) * jnp.sin(theta)


def wheel_current_gain(p: rwp.RWP):
    """(J + Jr) k / (J Jr), the current's coefficient in (3)."""
    J = rwp.inertia(p)
    return (J + p.Jr) * p.k / (J * p.Jr)


def wheel_accel(p: rwp.RWP, I, theta):
    """(3): theta_r'' = ((J + Jr) k / (J Jr)) I - a1 sin(theta)."""
    return wheel_current_gain(p) * I - a1(p) * jnp.sin(theta)


# ---- the pair of differentiators (10) + (12) as a loop estimator ----------------------------------------


def rwp_homd_rhs(params, xi, y, u):
    """d/dt [x̂_p1, x̂_p2, x̂_r1, x̂_r2] of (10) and (12); y = [theta measurement, theta_r measurement];
    ``params`` has the gains ``pend``, ``wheel`` and the ``model`` (an ``HOMDObserver`` or an observer built on it)."""
    I = u[0]
    th = y[0]
    dp = differentiator_rhs(params.pend, xi[0:2], th, pendulum_accel(params.model, I, th))
    dr = differentiator_rhs(params.wheel, xi[2:4], y[1], wheel_accel(params.model, I, th))
    return jnp.concatenate([dp, dr])


def _init_from_y(params, y):
    z = jnp.zeros_like(y[0])
    return jnp.stack([y[0], z, y[1], z])


def _out(params, xi, y):
    # law (8) uses the measured angle and the two velocity estimates
    return jnp.stack([y[0], xi[1], xi[2], xi[3]])


def observer_model(model: rwp.RWP | None = None) -> rwp.RWP:
    """The observer's model of the plant (Table 1 unless given; its constants are float64 array fields)."""
    return rwp.RWP() if model is None else model


class HOMDObserver(SampledObserver):
    """(10) + (12) as an engine estimator: input y = [theta, theta_r] (measured), output
    [y_theta, x̂_p2, x̂_r1, x̂_r2] = the vector law (8) multiplies by K (with K = [k1, k2, 0, k3]). Build with
    ``HOMDObserver.build(dt, pend=(k1, k2, alpha), wheel=..., model=..., substeps=..., hold=...)``."""

    pend: HOMDGains = None  # [k_p1, k_p2, α_p] of (10)
    wheel: HOMDGains = None  # [k_r1, k_r2, α_r] of (12)
    model: rwp.RWP = None  # the observer's model of the plant (Table 1)

    rhs = staticmethod(rwp_homd_rhs)
    init_xi = staticmethod(_init_from_y)
    out = staticmethod(_out)
    n_xi, n_y = 4, 2

    def __check_init__(self):
        check_gains(self, "pend", self.pend)
        check_gains(self, "wheel", self.wheel)
        check_observer_model(self, self.model)

    @classmethod
    def build(cls, dt: float, pend=(5.0, 12.0, 0.9), wheel=(5.0, 12.0, 0.9), model: rwp.RWP | None = None,
              **kw) -> "HOMDObserver":
        return cls(dt, as_gains(cls, "pend", pend), as_gains(cls, "wheel", wheel), observer_model(model), **kw)
