"""Two-wheeled inverted pendulum (Stumfoll MS thesis, §5.2, eqs. (72)-(81); Tables 8.1 and 8.2).

The thesis writes the nonlinear equations of motion in the pendulum angle theta, with theta = pi upright:

    (72)  (Ip + Mp l^2) theta'' - 2 km ke/(R r) x' + 2 km/R V + Mp g l sin(theta) = -Mp l x'' cos(theta)
    (73)  2 km/(R r) V = beta x'' + 2 km ke/(R r^2) x' + Mp l theta'' cos(theta) - Mp l theta'^2 sin(theta)

with beta = 2 Mw + 2 Iw/r^2 + Mp (80). The linear model, the filters and the controllers work with the tilt
phi = theta - pi (docs/models.md), so the plant's state is ``[x, x_dot, phi, phi_dot]`` and its upright equilibrium
is the origin. Input: the motor voltage ``V`` (the same voltage on both wheels).

(72)-(73) are linear in (x'', theta''); ``f`` solves the 2x2 system in closed form (its determinant
(Mp l cos theta)^2 - (Ip + Mp l^2) beta is negative for every theta, equal to -alpha of (81) upright).
sin(theta) and cos(theta) are evaluated as -sin(phi) and -cos(phi), so the upright equilibrium is exact in
floating point (sin(pi) in float64 is 1.2e-16, not 0).

The model has no conserved energy: the motor's back-EMF acts as viscous damping on x'.
``linear_model_closed_form`` is eq. (79) as printed; the tests check it against the autodiff linearisation of
(72)-(73) at phi = 0 for both parameter tables.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Plant, param

from jaxdip._public import public_dir

# not listed: STATE_NAMES (the plant's state_names) and the equations whose names repeat in other plant modules
# (f, energy, output_matrix): each stays reachable here, one name per concept holds for what is listed
__all__ = ["TABLES", "beta", "alpha", "accelerations", "linear_model_closed_form", "TWIP", "TWIPUnmodeled"]
__dir__ = public_dir(globals())

STATE_NAMES = ("x", "x_dot", "phi", "phi_dot")
# Table 8.1 is the field defaults of ``TWIP``; Table 8.2 differs in Iw, ke, km, Mp, Mw and R
TABLES = {
    "8.1": {},
    "8.2": dict(Ip=0.025, Iw=1.774e-4, ke=0.0034, km=0.2885, l=0.075, Mp=1.5752, Mw=0.1752, r=0.045, R=3.0),
}


def beta(p: "TWIP"):
    """Eq. (80): beta = 2 Mw + 2 Iw / r^2 + Mp."""
    return 2 * p.Mw + 2 * p.Iw / p.r**2 + p.Mp


def alpha(p: "TWIP"):
    """Eq. (81): alpha = Ip beta + 2 Mp l^2 (Mw + Iw / r^2)."""
    return p.Ip * beta(p) + 2 * p.Mp * p.l**2 * (p.Mw + p.Iw / p.r**2)


def accelerations(p: "TWIP", s_th, c_th, xd, thd, V):
    """(x'', theta'') from (72)-(73), given sin(theta), cos(theta), x', theta' and V.

    Rows of the 2x2 system M [x'', theta'']^T = b:
        (72): Mp l cos(th) x'' + (Ip + Mp l^2) theta'' = 2 km ke/(R r) x' - 2 km/R V - Mp g l sin(th)
        (73): beta x''         + Mp l cos(th) theta''  = 2 km/(R r) V - 2 km ke/(R r^2) x' + Mp l theta'^2 sin(th)
    """
    mlc = p.Mp * p.l * c_th
    jp = p.Ip + p.Mp * p.l**2
    be = beta(p)
    b1 = 2 * p.km * p.ke / (p.R * p.r) * xd - 2 * p.km / p.R * V - p.Mp * p.g * p.l * s_th
    b2 = 2 * p.km / (p.R * p.r) * V - 2 * p.km * p.ke / (p.R * p.r**2) * xd + p.Mp * p.l * thd**2 * s_th
    det = mlc * mlc - jp * be
    xdd = (mlc * b1 - jp * b2) / det
    thdd = (mlc * b2 - be * b1) / det
    return xdd, thdd


def f(p: "TWIP", x, u):
    """Continuous dynamics in the tilt coordinates ``[x, x_dot, phi, phi_dot]``, theta = pi + phi."""
    xd, phi, phid = x[1], x[2], x[3]
    V = jnp.reshape(u, (-1,))[0]
    # sin(pi + phi) = -sin(phi), cos(pi + phi) = -cos(phi); theta' = phi', theta'' = phi''.
    xdd, phidd = accelerations(p, -jnp.sin(phi), -jnp.cos(phi), xd, phid, V)
    return jnp.stack([xd, xdd, phid, phidd])


def linear_model_closed_form(p: "TWIP"):
    """(A, B) of eq. (79), exactly as printed, with beta (80) and alpha (81). State ``[x, x_dot, phi, phi_dot]``."""
    be = beta(p)
    al = alpha(p)
    kk = 2 * p.km * p.ke
    a22 = kk * (p.Mp * p.l * p.r - p.Ip - p.Mp * p.l**2) / (p.R * p.r**2 * al)
    a23 = p.Mp**2 * p.g * p.l**2 / al
    a42 = kk * (p.r * be - p.Mp * p.l) / (p.R * p.r**2 * al)
    a43 = p.Mp * p.g * p.l * be / al
    b2 = 2 * p.km * (p.Ip + p.Mp * p.l**2 - p.Mp * p.l * p.r) / (p.R * p.r * al)
    b4 = 2 * p.km * (p.Mp * p.l - p.r * be) / (p.R * p.r * al)
    z = jnp.zeros(())
    one = jnp.ones(())
    A = jnp.stack(
        [
            jnp.stack([z, one, z, z]),
            jnp.stack([z, a22, a23, z]),
            jnp.stack([z, z, z, one]),
            jnp.stack([z, a42, a43, z]),
        ]
    )
    B = jnp.stack([z, b2, z, b4]).reshape(4, 1)
    return A, B


class TWIP(Plant):
    """The TWIP: Table 8.1 of the thesis (SI units; g is not in the table, 9.81 is assumed) as array fields.
    ``TWIP.table("8.2")`` is the perturbed truth of §8.1.2 on."""

    Ip: jax.Array = param(0.025)  # pendulum body inertia about its centre of gravity, kg m^2
    Iw: jax.Array = param(1.183e-4)  # wheel inertia, kg m^2
    ke: jax.Array = param(0.00361)  # back-EMF constant, V s/rad
    km: jax.Array = param(0.11541)  # torque constant, N m/A
    l: jax.Array = param(0.075)  # wheel axle to the body's centre of gravity, m
    Mp: jax.Array = param(1.432)  # pendulum body mass, kg
    Mw: jax.Array = param(0.1168)  # mass of one wheel, kg
    r: jax.Array = param(0.045)  # wheel radius, m
    R: jax.Array = param(2.5)  # motor winding resistance, ohm
    g: jax.Array = param(9.81)

    state_names = STATE_NAMES
    input_names = ("V",)

    def __check_init__(self):
        checks.check_physical(self, positive=("Ip", "Iw", "l", "Mp", "Mw", "r", "R", "g"),
                              nonnegative=("ke", "km"))

    @classmethod
    def table(cls, which: str, **kw) -> "TWIP":
        """Table "8.1" (nominal: the parameters the estimators and the LQR design use) or "8.2" (perturbed: the
        'true' plant of the parameter-uncertainty studies, §8.1.2 on) of the thesis; ``kw`` sets other fields."""
        if which not in TABLES:
            raise ValueError(f"TWIP table must be one of {sorted(TABLES)}, got {which!r}")
        return cls(**TABLES[which], **kw)

    def vector_field(self, x, u):
        return f(self, x, u)


class TWIPUnmodeled(TWIP):
    """The TWIP with the unmodeled accelerations of (185) added to x'' and phi'' (as they enter (87)):

        d1 = g1 x' sin(freq x),   d2 = g2 x'^2        (thesis: g1 = 1/2, g2 = 1/4, freq = 180/pi printed)

    With g1 = g2 = 0 it is the TWIP (its vector field differs from ``TWIP``'s only by adding zeros)."""

    g1: jax.Array = param(0.0)
    g2: jax.Array = param(0.0)
    freq: jax.Array = param(180.0 / math.pi)

    def __check_init__(self):
        checks.check_physical(self, finite=("g1", "g2", "freq"))

    def unmodeled(self, x):
        """(d1, d2) of (185)."""
        return self.g1 * x[1] * jnp.sin(self.freq * x[0]), self.g2 * x[1] ** 2

    def vector_field(self, x, u):
        d1, d2 = self.unmodeled(x)
        return f(self, x, u) + jnp.stack([jnp.zeros(()), d1, jnp.zeros(()), d2])
