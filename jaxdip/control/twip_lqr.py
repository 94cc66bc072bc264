"""Discrete LQR of the two-wheeled inverted pendulum on its nominal linear model (Stumfoll §7.1-7.2).

The design model is the closed-form linearisation (79) at upright, state ``[x, x_dot, phi, phi_dot]``,
discretised exactly under a zero-order hold over ``dt`` (148): F = exp(A dt), G = int_0^dt exp(A s) ds B, both
from one exponential of the augmented matrix (``jaxdip.sim.discretize.zoh``).

About §7.1's formula G = F [I - exp(-A dt)] A^{-1} B: it is the same integral only when A is invertible. The
TWIP's A has a zero first column (the wheel position x is a pure integrator), so A^{-1} does not exist and
the printed formula cannot be evaluated; the integral itself is well defined (it equals the power series
sum_k A^k dt^(k+1)/(k+1)! B) and that is what ``zoh`` returns. ``tests/test_dmso.py`` checks the printed
formula against ``zoh`` on an invertible A and the series against ``zoh`` on the TWIP's A.

The gain is (150), K = (R + G^T S G)^{-1} G^T S F with S the stabilising solution of the DARE, and the law is
(149), u_k = -K (xhat_k - x_des). The thesis's weights (151)-(152) are R = 1000, Q = diag(10, 10, 1e-5, 1e-4);
the extra-control study of §8.2 uses other weights, hence ``Q`` and ``R`` are arguments. Everything is
differentiable in the plant parameters, Q, R (the DARE has an implicit-function JVP).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from jaxdip.control.designs import dlqr
from jaxdip.engine.memo import memoised
from jaxdip.plants import twip
from jaxdip.sim.discretize import zoh

from jaxdip._public import public_dir

__all__ = ["Q_THESIS", "R_THESIS", "TwipDesign", "twip_discrete", "twip_dlqr"]
__dir__ = public_dir(globals())

# (151)-(152): the weights of every simulation of §8.1
Q_THESIS = (10.0, 10.0, 1e-5, 1e-4)
R_THESIS = 1000.0


class TwipDesign(NamedTuple):
    K: jnp.ndarray  # (1, 4) LQR gain, u = -K x
    S: jnp.ndarray  # (4, 4) DARE solution
    E: jnp.ndarray  # (4,) closed-loop eigenvalues of F - G K (nominal model)
    F: jnp.ndarray  # (4, 4) exp(A dt)
    G: jnp.ndarray  # (4, 1) ZOH input matrix
    A: jnp.ndarray  # (4, 4) continuous (79)
    B: jnp.ndarray  # (4, 1)


def twip_discrete(params: twip.TWIP, dt):
    """(F, G, A, B): the exact ZOH discretisation (148) of the closed-form linear model (79)."""
    A, B = twip.linear_model_closed_form(params)
    d = zoh(A, B, dt)
    return d.Phi, d.W, A, B


def _weight(Q, n):
    Q = jnp.asarray(Q, dtype=jnp.float64)
    return jnp.diag(Q) if Q.ndim == 1 else Q.reshape(n, n)


@memoised(64)
def twip_dlqr(params: twip.TWIP | None = None, Q=Q_THESIS, R=R_THESIS, dt=0.01) -> TwipDesign:
    """Discrete LQR (150) for the TWIP's nominal linear model (Table 8.1 when None). ``Q``: 4 diagonal weights
    or a 4x4 matrix. A call with the same values as an earlier one returns that design (``jaxdip.engine.memo``):
    the experiments build each case's controller from the same nominal design, 20-50 ms each time."""
    params = twip.TWIP() if params is None else params
    F, G, A, B = twip_discrete(params, dt)
    Qm = _weight(Q, 4)
    Rm = jnp.atleast_2d(jnp.asarray(R, dtype=jnp.float64))
    K, S, E = dlqr(F, G, Qm, Rm)
    return TwipDesign(K=K, S=S, E=E, F=F, G=G, A=A, B=B)
