"""Luenberger observer (9) of the reaction-wheel pendulum on the full linearised state.

State xi = [theta, theta', theta_r, theta_r'], outputs theta and theta_r (both measured):

    xi' = A4 xi + B4 I + L ([theta, theta_r] - C4 xi),
    A4 = [[0, 1, 0, 0], [a1, 0, 0, 0], [0, 0, 0, 1], [-a1, 0, 0, 0]],   B4 = [0, -k/J, 0, k/J + k/Jr],
    C4 = [[1, 0, 0, 0], [0, 0, 1, 0]],   L in R^{4x2}.

Choice of L (the paper only says "approximately equal rise time" to the differentiators). We make the error
dynamics A4 - L C4 two decoupled blocks with the differentiators' structure,

    L = [[l_p1, 0], [l_p2 + a1, 0], [0, l_r1], [-a1, l_r2]]   =>   e_1' = e_2 - l_p1 e_1,  e_2' = -l_p2 e_1,
                                                                 e_3' = e_4 - l_r1 e_3,  e_4' = -l_r2 e_3,

i.e. the linear (α = 1) counterpart of (11)/(13), with l_1 = ω k_1 and l_2 = ω^2 k_2 (the HOMD gains scaled in
time by ω). ``matched_omega`` picks ω so that the 10-90% rise time of the velocity estimate after a velocity step
of a reference size equals the HOMD's (the HOMD's rise time depends on the step size: homogeneity of degree
α - 1 makes it scale as v^((1-α)/α); the linear one does not).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine import checks
from jaxdip.estimators import homd
from jaxdip.estimators.continuous import SampledObserver
from jaxdip.plants import rwp


from jaxdip._public import public_dir

__all__ = ["full_linear_model", "decoupled_gain", "luenberger_rhs", "velocity_step_rise_time", "matched_omega",
           "matched_gain", "LuenbergerObserver"]
__dir__ = public_dir(globals())


def full_linear_model(p: rwp.RWP):
    """(A4, B4, C4) of (9), input column from (2)-(3)."""
    a = homd.a1(p)
    dt = jnp.result_type(a)  # the model's (float32 inside a float32 loop)
    z = jnp.zeros((), dt)
    o = jnp.ones((), dt)
    A = jnp.stack([
        jnp.stack([z, o, z, z]),
        jnp.stack([a + z, z, z, z]),
        jnp.stack([z, z, z, o]),
        jnp.stack([-a + z, z, z, z]),
    ])
    J = rwp.inertia(p)
    B = jnp.stack([z, -p.k / J + z, z, p.k / J + p.k / p.Jr + z]).reshape(4, 1)
    C = jnp.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]], dt)
    return A, B, C


def decoupled_gain(p: rwp.RWP, lp1, lp2, lr1, lr2):
    """L making A4 - L C4 block-diagonal with blocks [[-l1, 1], [-l2, 0]] (see the module docstring)."""
    a = homd.a1(p)
    z = jnp.zeros(())
    return jnp.stack([
        jnp.stack([lp1 + z, z]),
        jnp.stack([lp2 + a, z]),
        jnp.stack([z, lr1 + z]),
        jnp.stack([-a + z, lr2 + z]),
    ])


def luenberger_rhs(params, xi, y, u):
    A, B, C = full_linear_model(params.model)
    return A @ xi + B[:, 0] * u[0] + params.L @ (y - C @ xi)


def _init_from_y(params, y):
    z = jnp.zeros_like(y[0])
    return jnp.stack([y[0], z, y[1], z])


def _out(params, xi, y):
    # law (8): measured angle, estimated velocities
    return jnp.stack([y[0], xi[1], xi[2], xi[3]])


# ---- rise-time matching ----------------------------------------------------------------------------------


@partial(jax.jit, static_argnums=(2, 3))
def _velocity_step_curve(g: homd.HOMDGains, v, h: float, n: int):
    """x̂_2(t_i), i = 1..n, of (11) from e = [0, -v] with RK4 steps of size h (jitted once per (h, n))."""

    def f(e):
        return homd.error_rhs(g, e)

    def step(e, _):
        k1 = f(e)
        k2 = f(e + 0.5 * h * k1)
        k3 = f(e + 0.5 * h * k2)
        k4 = f(e + h * k3)
        e = e + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        return e, e[1]

    e0 = jnp.stack([jnp.zeros_like(v), -v])
    _, e2 = jax.lax.scan(step, e0, None, length=n)
    return e2 + v


def velocity_step_rise_time(g: homd.HOMDGains, v: float, h: float = 1e-4, t_max: float = 5.0) -> float:
    """10-90% rise time of the velocity estimate of the differentiator (11) after a velocity step of size v.

    The estimate starts exact in position and at 0 in velocity while the true velocity is v, so the error
    starts at e = [0, -v]; the estimate x̂_2 = v + e_2 rises from 0 towards v. Fine RK4 steps of size h.
    """
    n = int(round(t_max / h))
    g = homd.HOMDGains(*(jnp.asarray(x, dtype=jnp.float64) for x in g))
    xhat2 = np.asarray(_velocity_step_curve(g, jnp.asarray(float(v)), float(h), n))
    t = (np.arange(n) + 1) * h
    i10 = np.argmax(xhat2 >= 0.1 * v)
    i90 = np.argmax(xhat2 >= 0.9 * v)
    if xhat2[i90] < 0.9 * v:
        return float("nan")
    return float(t[i90] - t[i10])


def matched_omega(g: homd.HOMDGains, v_ref: float) -> float:
    """ω such that the linear observer with gains (ω k1, ω^2 k2) has the HOMD's rise time at step size v_ref.

    The linear rise time scales exactly as 1/ω, so ω = t_r(linear, ω = 1) / t_r(HOMD, v_ref).
    """
    lin = homd.HOMDGains(g.k1, g.k2, jnp.asarray(1.0))
    return velocity_step_rise_time(lin, 1.0) / velocity_step_rise_time(g, v_ref)


def matched_gain(p: rwp.RWP, pend: homd.HOMDGains, wheel: homd.HOMDGains, v_ref_p: float, v_ref_r: float):
    """L of (9) with the rise times of (10) and (12) at velocity steps v_ref_p, v_ref_r; returns (L, ω_p, ω_r)."""
    wp = matched_omega(pend, v_ref_p)
    wr = matched_omega(wheel, v_ref_r)
    L = decoupled_gain(p, wp * pend.k1, wp**2 * pend.k2, wr * wheel.k1, wr**2 * wheel.k2)
    return L, wp, wr


class LuenbergerObserver(SampledObserver):
    """(9) as an engine estimator: input y = [theta, theta_r], output [y_theta, θ̂', θ̂_r, θ̂_r']; gain ``L``
    (4, 2) and the observer's ``model``. Build with ``LuenbergerObserver.build(dt, L, model, substeps=..., ...)``."""

    L: jnp.ndarray = None
    model: rwp.RWP = None

    rhs = staticmethod(luenberger_rhs)
    init_xi = staticmethod(_init_from_y)
    out = staticmethod(_out)
    n_xi, n_y = 4, 2

    def __check_init__(self):
        checks.check_real(self, "L", self.L)
        checks.check_shape(self, "L", self.L, (4, 2), "(4 observer states, 2 measurements [theta, theta_r])")
        checks.check_finite(self, "L", self.L)
        homd.check_observer_model(self, self.model)

    @classmethod
    def build(cls, dt: float, L, model: rwp.RWP | None = None, **kw) -> "LuenbergerObserver":
        checks.check_real(cls, "L", L)
        return cls(dt, jnp.asarray(L, dtype=jnp.float64), homd.observer_model(model), **kw)
