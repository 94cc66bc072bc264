"""Low-pass derivative filter (LDF): the velocity estimate the Quanser DIP loops used (paper Table 1).

Each measured position y passes through the second-order filter H(s) = w^2 s / (s^2 + 2 zeta w s + w^2):
with filter state (p, v),  p' = v,  v' = w^2 (y - p) - 2 zeta w v, and v is the derivative estimate. It is
discretised exactly under zero-order hold of y at the sample period, once, in ``init`` (so gradients with
respect to the cut-offs and the damping flow through the discretisation). The estimate is the raw measured
positions and the filtered derivatives. The filter's position state starts at the true initial positions (the
encoders read them) and its derivative state at zero.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, dtype_of, param
from jaxdip.sim.discretize import zoh


from jaxdip._public import public_dir

__all__ = ["LDF"]
__dir__ = public_dir(globals())


def _discretise(w, zeta, dt):
    A = jnp.array([[0.0, 1.0], [-(w**2), -2.0 * zeta * w]])
    B = jnp.array([[0.0], [w**2]])
    d = zoh(A, B, dt)
    return d.Phi, d.W[:, 0]


class LDF(Estimator):
    """The LDF for a plant whose state is [positions (n_pos), velocities (n_pos)] and whose first n_pos outputs
    are the positions: a cut-off ``omega`` per measured position and a damping ``zeta`` (scalar or per
    position); the number of positions and the sample period static. ``aux`` is the filter state (position,
    derivative) per channel. ``LDF.dip(dt)`` has the paper's settings."""

    omega: jax.Array = param()
    zeta: jax.Array = param()
    n_pos: int = eqx.field(static=True)
    dt: float = eqx.field(static=True)

    @classmethod
    def dip(cls, dt: float, cart_cutoff=100 * jnp.pi, angle_cutoff=20 * jnp.pi, zeta=0.9) -> "LDF":
        """The paper's settings: 100 pi rad/s for the cart, 20 pi rad/s for the angles, damping 0.9."""
        return cls(jnp.array([cart_cutoff, angle_cutoff, angle_cutoff], dtype=jnp.float64),
                   jnp.asarray(zeta, dtype=jnp.float64), n_pos=3, dt=dt)

    def __check_init__(self):
        checks.check_int(self, "n_pos", self.n_pos, 1)
        checks.check_scalar_or_vector(self, "omega", self.omega, self.n_pos, f"(one cut-off per position, n_pos={self.n_pos})")
        checks.check_scalar_or_vector(self, "zeta", self.zeta, self.n_pos, f"(n_pos={self.n_pos})")
        checks.check_positive(self, "omega", self.omega)
        checks.check_nonnegative(self, "zeta", self.zeta)
        checks.check_positive(self, "dt", self.dt)

    def io_sizes(self) -> dict:
        return {"out": (2 * self.n_pos, f"n_pos={self.n_pos} positions and their rates")}

    def init(self, key, x0):
        zeta = jnp.broadcast_to(self.zeta, self.omega.shape)
        Phi, W = jax.vmap(lambda w, z: _discretise(w, z, self.dt))(self.omega, zeta)
        x0 = jnp.asarray(x0, dtype_of(x0))
        filt = jnp.stack([x0[:self.n_pos], jnp.zeros(self.n_pos, x0.dtype)], axis=1)  # (p, 2)
        return (Phi, W, filt)

    def step(self, state, y, u_prev, key, k):
        Phi, W, filt = state
        y = y[:self.n_pos]
        xhat = jnp.concatenate([y, filt[:, 1]])
        filt = jnp.einsum("pij,pj->pi", Phi, filt) + W * y[:, None]
        return (Phi, W, filt), xhat, filt
