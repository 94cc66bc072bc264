"""Linearisation by autodiff and exact zero-order-hold discretisation."""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl



@partial(jax.jit, static_argnums=0)
def linearize(f, params, x0, u0):
    """(A, B) = (df/dx, df/du) at (x0, u0), by forward-mode autodiff.

    Jitted (with ``f`` static): op-by-op nested autodiff of the Lagrangian DIP takes seconds, compiled it
    takes milliseconds after the first call.
    """
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    u0 = jnp.atleast_1d(jnp.asarray(u0, dtype=jnp.float64))
    A = jax.jacfwd(f, argnums=1)(params, x0, u0)
    B = jax.jacfwd(f, argnums=2)(params, x0, u0)
    return A, B.reshape(x0.shape[0], u0.shape[0])


class Discrete(NamedTuple):
    Phi: jnp.ndarray  # e^{A h}
    Phi_inv: jnp.ndarray  # e^{-A h}, exact rather than a numerical inverse
    W: jnp.ndarray  # int_0^h e^{A s} ds B


@jax.jit
def zoh(A, B, h) -> Discrete:
    """Exact ZOH discretisation from one matrix exponential of the augmented matrix [[A, B], [0, 0]] h.

    exp([[A, B], [0, 0]] h) = [[Phi, W], [0, I]], so Phi and W come out of the same exponential with no
    integral approximated and no inverse of A (A may be singular: the DIP's cart position is an integrator).
    """
    A = jnp.asarray(A, dtype=jnp.float64)
    B = jnp.asarray(B, dtype=jnp.float64)
    B = B.reshape(A.shape[0], -1)
    n, m = B.shape
    M = jnp.zeros((n + m, n + m), dtype=A.dtype).at[:n, :n].set(A).at[:n, n:].set(B)
    E = jsl.expm(M * h)
    Phi_inv = jsl.expm(-A * h)
    return Discrete(Phi=E[:n, :n], Phi_inv=Phi_inv, W=E[:n, n:])


def linearize_discrete(f, params, x0, u0, h) -> Discrete:
    A, B = linearize(f, params, x0, u0)
    return zoh(A, B, h)
