"""Quanser double inverted pendulum on a cart (King thesis ch. 3, Bernstein et al.).

State ``[xc, alpha, theta, xc_dot, alpha_dot, theta_dot]``: cart position, lower link angle from the vertical,
angle of the upper link relative to the lower one; upright is the origin, counter-clockwise positive.
Input: motor voltage ``V``; the force on the cart is ``Fc = Kg Kt (rmp V - Kg Km xc_dot) / (Rm rmp^2)``.

Two variants:

* ``printed`` (default, used for reproduction): the equations of motion exactly as printed in the thesis,
  with the extra weight Mw riding on the cart. They differ from a Lagrangian derivation of the same linkage:
  the coupling between the links appears as cos(2 alpha + theta) / sin(2 alpha + theta) where the derivation
  gives cos(theta) / sin(theta), and the upper link's inertia I2 is missing from the alpha row. The printed
  form does not conserve energy; it is what the published gains and P were designed on.
* ``lagrangian``: M(q) q'' = Q - C(q, q') q' - dV/dq derived by autodiff from kinetic and potential
  energy of the same linkage (same parameters, same damping as generalised forces). Conserves energy when
  the damping and the input are zero.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Plant, param
from jaxdip.plants.trig import sincos

from jaxdip._public import public_dir

# not listed: STATE_NAMES (the plant's state_names) and the equations whose names repeat in other plant modules
# (f, energy, output_matrix): each stays reachable here, one name per concept holds for what is listed
__all__ = ["cart_force", "cart_mass", "solve_sym3", "f_printed", "kinetic_energy", "potential_energy", "f_lagrangian",
           "DIP"]
__dir__ = public_dir(globals())

STATE_NAMES = ("xc", "alpha", "theta", "xc_dot", "alpha_dot", "theta_dot")
STATE_UNITS = ("m", "rad", "rad", "m/s", "rad/s", "rad/s")


def cart_force(p: "DIP", xc_dot, V):
    return p.Kg * p.Kt * (p.rmp * V - p.Kg * p.Km * xc_dot) / (p.Rm * p.rmp**2)


def cart_mass(p: "DIP"):
    """Translational mass of the cart with the motor inertia reflected through the pinion and Mw on board."""
    return p.Mc + p.Mw + p.Jm * p.Kg**2 / p.rmp**2


def solve_sym3(m11, m12, m13, m22, m23, m33, b1, b2, b3):
    """Closed-form solve of a symmetric 3x3 system.

    Batched ``jnp.linalg.solve`` on 3x3 blocks lowers to one LAPACK call per item; the explicit adjugate is
    several times faster under vmap (measured with jaxdip bench; docs/models.md) and exact enough for these well-conditioned
    mass matrices (condition number ~1e2).
    """
    c11 = m22 * m33 - m23 * m23
    c12 = m13 * m23 - m12 * m33
    c13 = m12 * m23 - m13 * m22
    c22 = m11 * m33 - m13 * m13
    c23 = m12 * m13 - m11 * m23
    c33 = m11 * m22 - m12 * m12
    det = m11 * c11 + m12 * c12 + m13 * c13
    inv = 1.0 / det
    return (
        (c11 * b1 + c12 * b2 + c13 * b3) * inv,
        (c12 * b1 + c22 * b2 + c23 * b3) * inv,
        (c13 * b1 + c23 * b2 + c33 * b3) * inv,
    )


def _sin_cos(p: "DIP", a, th):
    """(sin a, cos a, sin th, cos th). "vectorised": jaxdip.plants.trig.sincos, about 1.6x a plant-only loop's
    throughput, and not the C library's last bits (docs/performance.md: where it is faster and where not)."""
    if p.trig == "vectorised":
        # one formula for both angles: with one per angle, dip-cpx-ldf's LDF loop ran 2.5x slower than with the C
        # library's trig when the power-series control's third derivative took this model (0.9x with one)
        s, c = sincos(jnp.stack([a, th]))
        return s[0], c[0], s[1], c[1]
    return jnp.sin(a), jnp.cos(a), jnp.sin(th), jnp.cos(th)


def f_printed(p: "DIP", x, u):
    """Equations of motion as printed in thesis §3.1.1, with Mw in the cart mass."""
    _xc, a, th, xcd, ad, thd = x[0], x[1], x[2], x[3], x[4], x[5]
    V = jnp.reshape(u, (-1,))[0]
    # four trig evaluations instead of six: the sums by the angle-addition identities (the trig calls are most
    # of the cost of a right-hand side; the identities agree with direct evaluation to a few ulp)
    s_a, c_a, s_t, c_t = _sin_cos(p, a, th)
    s_at, c_at = s_a * c_t + c_a * s_t, c_a * c_t - s_a * s_t
    s_2at, c_2at = s_a * c_at + c_a * s_at, c_a * c_at - s_a * s_at
    m_a = p.M1 * p.l1 + p.M2 * p.L1 + p.Mh * p.L1
    m2l2 = p.M2 * p.l2
    m2L1l2 = p.M2 * p.L1 * p.l2

    m11 = cart_mass(p) + p.M1 + p.M2 + p.Mh
    m12 = -(m_a * c_a + m2l2 * c_at)
    m13 = -m2l2 * c_at
    m22 = p.M1 * p.l1**2 + p.I1 + p.M2 * p.L1**2 + p.Mh * p.L1**2 + p.M2 * p.l2**2 + 2 * m2L1l2 * c_2at
    m23 = m2L1l2 * c_2at + p.M2 * p.l2**2
    m33 = p.M2 * p.l2**2 + p.I2

    Fc = cart_force(p, xcd, V)
    b1 = Fc - p.Bc * xcd - ((m_a * s_a + m2l2 * s_at) * ad + 2 * m2l2 * s_at * thd) * ad - m2l2 * s_at * thd**2
    b2 = (
        -(p.B1 - 2 * m2L1l2 * s_2at * (ad + thd)) * ad
        + m2L1l2 * s_2at * thd**2
        + p.g * m_a * s_a
        + p.g * m2l2 * s_at
    )
    b3 = m2L1l2 * s_2at * ad**2 - p.B2 * thd + p.g * m2l2 * s_at
    xcdd, add, thdd = solve_sym3(m11, m12, m13, m22, m23, m33, b1, b2, b3)
    return jnp.stack([xcd, ad, thd, xcdd, add, thdd])


# ---- Lagrangian variant -------------------------------------------------------------------------------


def kinetic_energy(p: "DIP", q, qd):
    xc, a, th = q[0], q[1], q[2]
    xcd, ad, thd = qd[0], qd[1], qd[2]
    # Centres of mass: lower link at l1 and hinge mass at L1 along the lower link; upper link at l2 beyond the
    # hinge along the absolute angle alpha + theta. x to the right, counter-clockwise angles, so a positive
    # angle moves a point in -x.
    v1 = jnp.stack([xcd - p.l1 * jnp.cos(a) * ad, -p.l1 * jnp.sin(a) * ad])
    vh = jnp.stack([xcd - p.L1 * jnp.cos(a) * ad, -p.L1 * jnp.sin(a) * ad])
    w2 = ad + thd
    v2 = jnp.stack(
        [
            xcd - p.L1 * jnp.cos(a) * ad - p.l2 * jnp.cos(a + th) * w2,
            -p.L1 * jnp.sin(a) * ad - p.l2 * jnp.sin(a + th) * w2,
        ]
    )
    del xc
    return 0.5 * (
        cart_mass(p) * xcd**2
        + p.M1 * v1 @ v1
        + p.I1 * ad**2
        + p.Mh * vh @ vh
        + p.M2 * v2 @ v2
        + p.I2 * w2**2
    )


def potential_energy(p: "DIP", q):
    a, th = q[1], q[2]
    return p.g * ((p.M1 * p.l1 + p.Mh * p.L1 + p.M2 * p.L1) * jnp.cos(a) + p.M2 * p.l2 * jnp.cos(a + th))


def energy(p: "DIP", x):
    return kinetic_energy(p, x[:3], x[3:]) + potential_energy(p, x[:3])


def f_lagrangian(p: "DIP", x, u):
    q, qd = x[:3], x[3:]
    V = jnp.reshape(u, (-1,))[0]
    T_qd = jax.grad(kinetic_energy, argnums=2)
    M = jax.jacfwd(T_qd, argnums=2)(p, q, qd)  # mass matrix d2T/dqd2
    C = jax.jacfwd(T_qd, argnums=1)(p, q, qd)  # d2T/dqd dq
    dT_dq = jax.grad(kinetic_energy, argnums=1)(p, q, qd)
    dV_dq = jax.grad(potential_energy, argnums=1)(p, q)
    Q = jnp.stack([cart_force(p, qd[0], V) - p.Bc * qd[0], -p.B1 * qd[1], -p.B2 * qd[2]])
    rhs = Q - C @ qd + dT_dq - dV_dq
    qdd = jnp.stack(solve_sym3(M[0, 0], M[0, 1], M[0, 2], M[1, 1], M[1, 2], M[2, 2], rhs[0], rhs[1], rhs[2]))
    return jnp.concatenate([qd, qdd])


# ---- the plant ----------------------------------------------------------------------------------------------


class DIP(Plant):
    """The DIP: the Table 3.3 parameters of the thesis (SI units) are its array fields, the variant
    (``"printed"``, the default, or ``"lagrangian"``, module doc) is static.

    ``trig`` (static) picks how the printed equations evaluate sin and cos: ``"library"`` (the default, the C
    library's, as every published number of this project was computed) or ``"vectorised"``
    (``jaxdip.plants.trig.sincos``: within a few ulp of it; the bench's LQR loop at 4096 seeds runs about 1.6x
    faster on a CPU, dip-cpx-ldf's CPX and LDF loops about 1.5x, but the experiments' quick runs, mostly
    compilation, were slower; docs/performance.md). Loops with
    quantised encoders (dip-cpx-ldf) amplify any last-bit difference, so there the two give different
    trajectories and statistics that agree only within their intervals."""

    Bc: jax.Array = param(5.4)  # viscous damping at the motor pinion
    B1: jax.Array = param(0.0024)  # viscous damping at the lower pendulum axis
    B2: jax.Array = param(0.0024)  # viscous damping at the upper pendulum axis
    g: jax.Array = param(9.81)
    I1: jax.Array = param(2.6347e-4)  # lower link inertia about its centre of gravity
    I2: jax.Array = param(1.1987e-3)  # upper link inertia about its centre of gravity
    Jm: jax.Array = param(3.9e-7)  # motor rotor inertia
    Kg: jax.Array = param(3.71)  # gearbox ratio
    Km: jax.Array = param(0.00767)  # back-EMF constant
    Kt: jax.Array = param(0.00767)  # torque constant
    l1: jax.Array = param(0.1143)  # pivot to lower link's centre of gravity
    l2: jax.Array = param(0.1778)  # hinge to upper link's centre of gravity
    L1: jax.Array = param(0.2096)  # total length of the lower link
    L2: jax.Array = param(0.3365)  # total length of the upper link (not in the dynamics)
    Mc: jax.Array = param(0.57)
    Mh: jax.Array = param(0.170)  # hinge mass, at distance L1 from the pivot
    Mw: jax.Array = param(0.37)  # extra weight on the cart
    M1: jax.Array = param(0.072)
    M2: jax.Array = param(0.127)
    Rm: jax.Array = param(2.6)
    rmp: jax.Array = param(6.35e-3)
    variant: str = eqx.field(default="printed", static=True)
    trig: str = eqx.field(default="library", static=True)

    state_names = STATE_NAMES
    input_names = ("V",)

    def __check_init__(self):
        checks.check_choice(self, "variant", self.variant, ("printed", "lagrangian"))
        checks.check_choice(self, "trig", self.trig, ("library", "vectorised"))
        checks.check_physical(self, positive=("g", "I1", "I2", "Kg", "l1", "l2", "L1", "L2", "Mc", "M1",
                                              "M2", "Rm", "rmp"),
                              nonnegative=("Bc", "B1", "B2", "Jm", "Km", "Kt", "Mh", "Mw"))  # Kt = Km = 0: no motor

    def vector_field(self, x, u):
        return (f_printed if self.variant == "printed" else f_lagrangian)(self, x, u)

    def energy(self, x):
        return energy(self, x)
