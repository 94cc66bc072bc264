"""Coulomb friction on the DIP's cart, for studies of what the printed model leaves out.

The printed model has only viscous damping. A dry (Coulomb) friction force F_f sign(xc_dot) opposing the cart
acts where the motor's force does, so it is exactly a change of the applied voltage: the cart force
Fc = Kg Kt (rmp V - Kg Km xc_dot) / (Rm rmp^2) moves by Kg Kt / (Rm rmp) per volt, and a force F is the voltage
F Rm rmp / (Kg Kt). The sign is smoothed as tanh(xc_dot / v_smooth) so that RK4 under a zero-order hold sees a
Lipschitz field (at v_smooth = 1 mm/s and a 1.5 kg cart, the friction's local rate F / (v_smooth m) is about
700 /s for 1 N, well inside RK4's stability at 0.1 ms sub-steps). It is a truth-only plant: controllers and
estimators keep designing on the wrapped ``DIP``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Plant, param
from jaxdip.plants.dip import DIP, STATE_NAMES


from jaxdip._public import public_dir

__all__ = ["volts_per_newton", "CartFriction"]
__dir__ = public_dir(globals())


def volts_per_newton(p: DIP):
    """The voltage change that changes the cart force by 1 N (at any cart velocity)."""
    return p.Rm * p.rmp / (p.Kg * p.Kt)


class CartFriction(Plant):
    """``plant`` with a Coulomb friction force of ``coulomb`` newtons on the cart (smoothed at ``v_smooth``
    m/s)."""

    plant: DIP
    coulomb: jax.Array = param(0.0)
    v_smooth: jax.Array = param(1e-3)

    state_names = STATE_NAMES
    input_names = ("V",)

    def __check_init__(self):
        if not isinstance(self.plant, DIP):
            raise checks.ArgumentTypeError(f"CartFriction: plant must be a DIP, got {type(self.plant).__name__}")
        checks.check_nonnegative(self, "coulomb", self.coulomb)
        checks.check_positive(self, "v_smooth", self.v_smooth)

    def friction_force(self, x):
        return self.coulomb * jnp.tanh(x[3] / self.v_smooth)

    def vector_field(self, x, u):
        return self.plant.vector_field(x, u - self.friction_force(x) * volts_per_newton(self.plant))

    def equilibrium(self):
        return self.plant.equilibrium()
