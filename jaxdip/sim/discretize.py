"""Exact zero-order-hold discretisation of a linear(ised) model (linearise a plant with ``jaxdip.linearize``)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["Discrete", "zoh"]
__dir__ = public_dir(globals())


class Discrete(NamedTuple):
    Phi: jnp.ndarray  # e^{A h}
    Phi_inv: jnp.ndarray  # e^{-A h}, exact rather than a numerical inverse
    W: jnp.ndarray  # int_0^h e^{A s} ds B


def zoh(A, B, h) -> Discrete:
    """Exact ZOH discretisation from one matrix exponential of the augmented matrix [[A, B], [0, 0]] h.

    exp([[A, B], [0, 0]] h) = [[Phi, W], [0, I]], so Phi and W come out of the same exponential with no
    integral approximated and no inverse of A (A may be singular: the DIP's cart position is an integrator).
    A is (n, n), B (n, m) or (n,), h > 0 a scalar: checked before anything is compiled.
    """
    for name, v in (("A", A), ("B", B), ("h", h)):
        checks.check_real("zoh", name, v)
    n = checks.check_square("zoh", "A", A)
    shape_b = checks.shape_of(B)
    if len(shape_b) not in (1, 2) or shape_b[0] != n:
        checks.fail("zoh", f"B must be ({n}, m) or ({n},) for a {n}-state model, got {checks.fmt_shape(shape_b)}")
    checks.check_ndim("zoh", "h", h, (0,), "a scalar (the sample period)")
    checks.check_finite("zoh", "A", A)
    checks.check_finite("zoh", "B", B)
    checks.check_positive("zoh", "h", h)
    return _zoh(A, B, h)


@jax.jit
def _zoh(A, B, h) -> Discrete:
    A = jnp.asarray(A, dtype=jnp.float64)
    B = jnp.asarray(B, dtype=jnp.float64)
    B = B.reshape(A.shape[0], -1)
    n, m = B.shape
    M = jnp.zeros((n + m, n + m), dtype=A.dtype).at[:n, :n].set(A).at[:n, n:].set(B)
    E = jsl.expm(M * h)
    Phi_inv = jsl.expm(-A * h)
    return Discrete(Phi=E[:n, :n], Phi_inv=Phi_inv, W=E[:n, n:])
