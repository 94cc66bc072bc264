"""Reaction-wheel pendulum (Aranovskiy et al., §II: Table 1, eqs. (1)-(4); Table 2).

theta is the pendulum's angle from the upright vertical, theta_r the wheel's angle *relative to the pendulum
body*. With J = Jp + mp lp^2 + mr lr^2 and ml = mp lp + mr lr, the Lagrangian of the paper is

    L = 1/2 J theta'^2 + 1/2 Jr (theta_r' + theta')^2 - ml g cos(theta)

and, without friction and with the motor current I as input (fast inner current loop, torque k I),

    (2)  theta''   = -(k/J) I + (ml g/J) sin(theta)
    (3)  theta_r'' = ((J + Jr) k / (J Jr)) I - (ml g/J) sin(theta).

Plant state ``[theta, theta_dot, theta_r, theta_r_dot]``; input ``I`` (A). The upright equilibrium is the origin
(theta_r is free: any theta_r with the other states zero is an equilibrium).

The controllers and observers of the paper use the reduced state x = [theta, theta_dot, theta_r_dot] of (4).
The B printed in (4) is [0, k/J, k/J + k/Jr]; its second entry has the wrong sign: (2), (3) and the observer
(9) all give -k/J, and only with -k/J do the Table 2 gains make A - BK Hurwitz (docs/models.md records this; the
tests show both). ``reduced_linear_model`` takes the column from (2)-(3).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Plant, param

from jaxdip._public import public_dir

# not listed: STATE_NAMES (the plant's state_names) and the equations whose names repeat in other plant modules
# (f, energy, output_matrix): each stays reachable here, one name per concept holds for what is listed
__all__ = ["REDUCED_STATE_NAMES", "PENDULUM_ANGLE_RESOLUTION", "WHEEL_ANGLE_RESOLUTION", "SAMPLING_HZ", "DT",
           "K_TABLE2", "inertia", "mass_moment", "reduced_linear_model", "reduced_output_matrix", "reduce_state", "RWP"]
__dir__ = public_dir(globals())

STATE_NAMES = ("theta", "theta_dot", "theta_r", "theta_r_dot")
REDUCED_STATE_NAMES = ("theta", "theta_dot", "theta_r_dot")

# Sensors and sampling of the experimental setup (Table 1).
PENDULUM_ANGLE_RESOLUTION = 6.28e-4  # rad
WHEEL_ANGLE_RESOLUTION = 6.54e-2  # rad
SAMPLING_HZ = 500.0
DT = 1.0 / SAMPLING_HZ  # s

# LQR gains of Table 2, u = -K x on the reduced state [theta, theta_dot, theta_r_dot] (law (5)/(8)).
K_TABLE2 = (-582.0, -83.0, -1.2)


def inertia(p: "RWP"):
    """J = Jp + mp lp^2 + mr lr^2: the pendulum with the wheel as a point mass, about the pivot."""
    return p.Jp + p.mp * p.lp**2 + p.mr * p.lr**2


def mass_moment(p: "RWP"):
    """ml = mp lp + mr lr."""
    return p.mp * p.lp + p.mr * p.lr


def f(p: "RWP", x, u):
    """Continuous dynamics (2)-(3) on ``[theta, theta_dot, theta_r, theta_r_dot]``."""
    th, thd, thrd = x[0], x[1], x[3]
    I = jnp.reshape(u, (-1,))[0]
    J = inertia(p)
    grav = mass_moment(p) * p.g / J * jnp.sin(th)
    thdd = -p.k / J * I + grav
    thrdd = (J + p.Jr) * p.k / (J * p.Jr) * I - grav
    return jnp.stack([thd, thdd, thrd, thrdd])


def energy(p: "RWP", x):
    """E = 1/2 J theta'^2 + 1/2 Jr (theta_r' + theta')^2 + ml g cos(theta); conserved when I = 0."""
    th, thd, thrd = x[0], x[1], x[3]
    return 0.5 * inertia(p) * thd**2 + 0.5 * p.Jr * (thrd + thd) ** 2 + mass_moment(p) * p.g * jnp.cos(th)


def reduced_linear_model(p: "RWP"):
    """(A, B) of (4) on x = [theta, theta_dot, theta_r_dot], with B = [0, -k/J, k/J + k/Jr] from (2)-(3)."""
    J = inertia(p)
    a = mass_moment(p) * p.g / J
    z = jnp.zeros(())
    one = jnp.ones(())
    A = jnp.stack([jnp.stack([z, one, z]), jnp.stack([a + z, z, z]), jnp.stack([-a + z, z, z])])
    B = jnp.stack([z, -p.k / J + z, p.k / J + p.k / p.Jr + z]).reshape(3, 1)
    return A, B


def reduced_output_matrix():
    """C of (4): the pendulum angle theta is measured."""
    return jnp.array([[1.0, 0.0, 0.0]])


def reduce_state(x):
    """[theta, theta_dot, theta_r, theta_r_dot] -> [theta, theta_dot, theta_r_dot]."""
    return jnp.stack([x[..., 0], x[..., 1], x[..., 3]], axis=-1)


class RWP(Plant):
    """The reaction-wheel pendulum: Table 1 of the paper (SI units; g is not in the table, 9.81 is assumed) as
    array fields; input the motor current I."""

    mp: jax.Array = param(0.58)  # pendulum mass, kg
    lp: jax.Array = param(0.10)  # pivot to the pendulum's centre of mass, m
    Jp: jax.Array = param(3.8e-3)  # pendulum inertia about its centre of mass, kg m^2
    mr: jax.Array = param(0.35)  # reaction wheel mass, kg
    lr: jax.Array = param(0.22)  # pivot to the wheel axis, m
    Jr: jax.Array = param(12.48e-4)  # wheel inertia, kg m^2
    k: jax.Array = param(3.69e-2)  # current-to-torque gain, N m/A
    g: jax.Array = param(9.81)

    state_names = STATE_NAMES
    input_names = ("I",)

    def __check_init__(self):
        checks.check_physical(self, positive=("mp", "lp", "Jp", "mr", "lr", "Jr", "g"), nonnegative=("k",))

    def vector_field(self, x, u):
        return f(self, x, u)

    def energy(self, x):
        return energy(self, x)
