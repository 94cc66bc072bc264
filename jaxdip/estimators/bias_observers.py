"""Bias observers for the reaction-wheel pendulum with a biased angle sensor y = theta + d (Aranovskiy et al.,
§IV-V).

Every observer here is a loop estimator (``jaxdip.estimators.continuous``) whose output is the vector the control
law multiplies by K = [k1, k2, 0, k3]: [y - d̂, θ̂', θ̂_r, θ̂_r']. So (18) and (23), u = -K [y - d̂, ...], are the
ordinary state feedback on the estimator's output, and the bias estimate is d̂ = y - (output)_0.

Low-pass observer (17) with the differentiators (used with law (23), Fig. 5):

    d̂' = γ_d (y - d̂),
    (10), (12) run on the corrected measurement y - d̂ (innovation and model term sin(y - d̂)).

The paper does not say which measurement the differentiators get in the low-pass experiment. With the raw y
they would keep the steady-state velocity errors (15) even when d̂ = d, and the wheel would not stop, so the
corrected one is the only reading under which Fig. 5 can stabilise; §V-B does the same for (24).

Low-pass observer with measured velocities, law (18) (the setting of Proposition 2): the sensor delivers
[theta + d, theta_r, theta', theta_r'] and only d̂ is estimated.

Reduced-order observer (21), velocity measured: with z = [theta, theta', d] and β_z = -(k/J) I + a1 sin(y)
- a1 cos(y) ẑ3,

    v' = β_z,   ẑ3 = L0 (v - z2),   d̂ = ẑ3,      so that e3' = -L0 a1 cos(y) e3   (22).

Joint observer (24), velocity from the differentiator (Fig. 6):

    ẑ1' = ẑ2 - k_p1 ⌈ẑ1 + ẑ3 - y⌋^α_p,
    ẑ2' = β_z - k_p2 ⌈ẑ1 + ẑ3 - y⌋^(2α_p - 1),
    v'  = β_z,     ẑ3 = L0 (v - ẑ2),     d̂ = ẑ3,

and the wheel differentiator (12) with the same linearised gravity term, θ̂_r'' model = ((J + Jr)k/(J Jr)) I
- a1 (sin y - cos(y) ẑ3). ẑ3 is an algebraic function of (v, ẑ2). With s = [e1 + e3, e2, e3] (e = ẑ - z) the
error dynamics is (25) (``joint_error_rhs``; the paper writes cos(z1) where the derivation gives cos(y): equal
under Assumption 1). The observer starts at v = ẑ2 = 0, i.e. d̂(0) = 0.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.estimators import homd
from jaxdip.estimators.continuous import SampledObserver
from jaxdip.estimators.homd import spow


from jaxdip._public import public_dir

__all__ = ["lowpass_rhs", "beta_z", "joint_bias", "joint_rhs", "joint_error_rhs", "LowpassHOMD", "LowpassMeasured",
           "ReducedOrderMeasured", "JointObserver"]
__dir__ = public_dir(globals())


def _f(v):
    return jnp.asarray(v, dtype=jnp.float64)


def _scalar(owner, name: str, v, positive: bool = False, nonnegative: bool = False) -> None:
    if v is None or isinstance(v, (str, bytes)):
        raise checks.ArgumentTypeError(f"{checks.owner_name(owner)}: {name} must be a number, got {v!r}")
    checks.check_real(owner, name, v)
    checks.check_ndim(owner, name, v, (0,), "a scalar")
    checks.check_finite(owner, name, v)
    if positive:
        checks.check_positive(owner, name, v)
    if nonnegative:
        checks.check_nonnegative(owner, name, v)


def _check_homd_parts(obs) -> None:
    # the HOMD's gains and model, which LowpassHOMD and JointObserver take over from ``build``'s HOMDObserver
    homd.check_gains(obs, "pend", obs.pend)
    homd.check_gains(obs, "wheel", obs.wheel)
    homd.check_observer_model(obs, obs.model)


def _check_homd_arg(owner, h) -> None:
    if not isinstance(h, homd.HOMDObserver):
        raise checks.ArgumentTypeError(f"{checks.owner_name(owner)}: h must be a HOMDObserver (its gains, model "
                                       f"and period are taken over), got {type(h).__name__}")


# ---- low-pass (17) ----------------------------------------------------------------------------------------


def lowpass_rhs(params, xi, y, u):
    """xi = [x̂_p1, x̂_p2, x̂_r1, x̂_r2, d̂]; y = [theta + d, theta_r]."""
    dhat = xi[4]
    yc = jnp.stack([y[0] - dhat, y[1]])
    dx = homd.rwp_homd_rhs(params, xi[:4], yc, u)
    return jnp.concatenate([dx, (params.gamma_d * (y[0] - dhat))[None]])


def _lp_init(params, y):
    z = jnp.zeros_like(y[0])
    return jnp.stack([y[0] - params.d0, z, y[1], z, params.d0 + z])


def _lp_out(params, xi, y):
    return jnp.stack([y[0] - xi[4], xi[1], xi[2], xi[3]])


def _lpm_rhs(params, xi, y, u):
    return (params.gamma_d * (y[0] - xi[0]))[None]


def _lpm_init(params, y):
    return (params.d0 + jnp.zeros_like(y[0]))[None]


def _measured_out(y, dhat):
    return jnp.stack([y[0] - dhat, y[2], y[1], y[3]])


# ---- reduced-order (21) and joint (24) ----------------------------------------------------------------------


def beta_z(model, I, y, z3hat):
    """β_z of (20): -(k/J) I + a1 sin(y) - a1 cos(y) ẑ3."""
    a = homd.a1(model)
    return homd.pendulum_accel(model, I, y) - a * jnp.cos(y) * z3hat


def _ro_rhs(params, xi, y, u):
    z3 = params.L0 * (xi[0] - y[2])
    return beta_z(params.model, u[0], y[0], z3)[None]


def _ro_init(params, y):
    # v(0) = z2(0): d̂(0) = 0
    return y[2][None]


def joint_bias(params, xi):
    """ẑ3 = L0 (v - ẑ2)."""
    return params.L0 * (xi[2] - xi[1])


def joint_rhs(params, xi, y, u):
    """xi = [ẑ1, ẑ2, v, x̂_r1, x̂_r2]; y = [theta + d, theta_r]."""
    g, m = params.pend, params.model
    I = u[0]
    z3 = joint_bias(params, xi)
    beta = beta_z(m, I, y[0], z3)
    s1 = xi[0] + z3 - y[0]
    dz1 = xi[1] - g.k1 * spow(s1, g.alpha)
    dz2 = beta - g.k2 * spow(s1, 2.0 * g.alpha - 1.0)
    a = homd.a1(m)
    acc_r = homd.wheel_current_gain(m) * I - a * (jnp.sin(y[0]) - jnp.cos(y[0]) * z3)
    dr = homd.differentiator_rhs(params.wheel, xi[3:5], y[1], acc_r)
    return jnp.concatenate([jnp.stack([dz1, dz2, beta]), dr])


def _joint_init(params, y):
    z = jnp.zeros_like(y[0])
    return jnp.stack([y[0], z, z, y[1], z])


def _joint_out(params, xi, y):
    return jnp.stack([y[0] - joint_bias(params, xi), xi[1], xi[3], xi[4]])


def joint_error_rhs(g: homd.HOMDGains, L0, a1_cos, s):
    """The error dynamics (25) in s = [e1 + e3, e2, e3], with a1_cos = a1 cos(·)."""
    p1 = spow(s[0], g.alpha)
    p2 = spow(s[0], 2.0 * g.alpha - 1.0)
    return jnp.stack([
        s[1] - g.k1 * p1 + L0 * g.k2 * p2,
        -a1_cos * s[2] - g.k2 * p2,
        L0 * g.k2 * p2,
    ])


# ---- as engine estimators --------------------------------------------------------------------------------


def _on_homd(cls, h: homd.HOMDObserver, *extra):
    # the HOMD's gains, model, period and integration settings, and the observer's own fields
    return cls(h.dt, h.pend, h.wheel, h.model, *extra, substeps=h.substeps, hold=h.hold)


class LowpassHOMD(SampledObserver):
    """(17) + (10) + (12) on y - d̂; output [y - d̂, θ̂', θ̂_r, θ̂_r'] for law (23). Build with
    ``LowpassHOMD.build(homd_observer, gamma_d, d0)`` (the HOMD's gains, model and period)."""

    pend: homd.HOMDGains = None
    wheel: homd.HOMDGains = None
    model: object = None
    gamma_d: jnp.ndarray = None  # γ_d of (17)
    d0: jnp.ndarray = None  # initial bias estimate

    rhs = staticmethod(lowpass_rhs)
    init_xi = staticmethod(_lp_init)
    out = staticmethod(_lp_out)
    n_xi, n_y = 5, 2

    def __check_init__(self):
        _check_homd_parts(self)
        _scalar(self, "gamma_d", self.gamma_d, nonnegative=True)  # 0: the bias estimate stays at d0
        _scalar(self, "d0", self.d0)

    @classmethod
    def build(cls, h: homd.HOMDObserver, gamma_d=0.05, d0=0.0) -> "LowpassHOMD":
        _check_homd_arg(cls, h)
        _scalar(cls, "gamma_d", gamma_d)
        _scalar(cls, "d0", d0)
        return _on_homd(cls, h, _f(gamma_d), _f(d0))


def _lpm_out(p, xi, y):
    return _measured_out(y, xi[0])


class LowpassMeasured(SampledObserver):
    """(17) with measured velocities, for law (18): input y = [theta + d, theta_r, theta', theta_r'], output
    [y - d̂, theta', theta_r, theta_r'] (Proposition 2's setting). ``LowpassMeasured.build(dt, gamma_d, d0)``."""

    gamma_d: jnp.ndarray = None
    d0: jnp.ndarray = None

    rhs = staticmethod(_lpm_rhs)
    init_xi = staticmethod(_lpm_init)
    out = staticmethod(_lpm_out)
    n_xi, n_y = 1, 4

    def __check_init__(self):
        _scalar(self, "gamma_d", self.gamma_d, nonnegative=True)
        _scalar(self, "d0", self.d0)

    @classmethod
    def build(cls, dt: float, gamma_d=0.05, d0=0.0, **kw) -> "LowpassMeasured":
        _scalar(cls, "gamma_d", gamma_d)
        _scalar(cls, "d0", d0)
        return cls(dt, _f(gamma_d), _f(d0), **kw)


def _ro_out(p, xi, y):
    return _measured_out(y, p.L0 * (xi[0] - y[2]))


class ReducedOrderMeasured(SampledObserver):
    """(21) with the measured velocity z2 = theta': input y = [theta + d, theta_r, theta', theta_r'], output
    [y - ẑ3, theta', theta_r, theta_r'] (so law (23) with exact velocities).
    ``ReducedOrderMeasured.build(dt, model, L0)``."""

    model: object = None
    L0: jnp.ndarray = None

    rhs = staticmethod(_ro_rhs)
    init_xi = staticmethod(_ro_init)
    out = staticmethod(_ro_out)
    n_xi, n_y = 1, 4

    def __check_init__(self):
        homd.check_observer_model(self, self.model)
        # (22): e3' = -L0 a1 cos(y) e3 converges only for L0 > 0 (with a1 > 0, |y| < pi/2)
        _scalar(self, "L0", self.L0, positive=True)

    @classmethod
    def build(cls, dt: float, model, L0=0.01, **kw) -> "ReducedOrderMeasured":
        _scalar(cls, "L0", L0)
        return cls(dt, homd.observer_model(model), _f(L0), **kw)


class JointObserver(SampledObserver):
    """(24) + (12); output [y - d̂, θ̂', θ̂_r, θ̂_r'] for law (23). Build with ``JointObserver.build(homd_observer,
    L0)`` (the HOMD's gains, model and period)."""

    pend: homd.HOMDGains = None
    wheel: homd.HOMDGains = None
    model: object = None
    L0: jnp.ndarray = None

    rhs = staticmethod(joint_rhs)
    init_xi = staticmethod(_joint_init)
    out = staticmethod(_joint_out)
    n_xi, n_y = 5, 2

    def __check_init__(self):
        _check_homd_parts(self)
        _scalar(self, "L0", self.L0, positive=True)

    @classmethod
    def build(cls, h: homd.HOMDObserver, L0=0.01) -> "JointObserver":
        _check_homd_arg(cls, h)
        _scalar(cls, "L0", L0)
        return _on_homd(cls, h, _f(L0))
