"""The two 2-D discrete-time examples of thesis §2.7 (relaxed projection control found by ensemble Kalman search).

* §2.7.1, linear, of the form (2.15):  x_{k+1} = A x_k + B u_k with
  A = [[.9974, .0539], [-.1078, 1.1591]], B = [.0013, .0539]^T  (open-loop unstable, controllable).
* §2.7.2, nonlinear, of the form (2.7): x_{k+1} = f(x_k) + g(x_k) u_k with
  f(x) = [2.2 sin(.5 x1) + .1 x2,  .1 x1^2 + 1.8 x2],  g(x) = [0, 2 + .1 cos(x2)].

Both are discrete plants: they provide ``step(params, x, u)`` and leave ``f`` as None. Their parameters are
pytrees; the defaults are read-only NumPy float64 arrays / Python floats, so importing this module does not
start a JAX backend, and the leaves are converted on use (jit, grad and vmap over params all work).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxdip.plants.base import Plant

STATE_NAMES = ("x1", "x2")


def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


class LinearParams(NamedTuple):
    """§2.7.1. B is stored as a 2x1 column."""

    A: np.ndarray = _frozen([[0.9974, 0.0539], [-0.1078, 1.1591]])
    B: np.ndarray = _frozen([[0.0013], [0.0539]])


class NonlinearParams(NamedTuple):
    """§2.7.2: f(x) = [a sin(w x1) + c x2, d x1^2 + e x2], g(x) = [0, g0 + g1 cos(x2)]."""

    a: float = 2.2
    w: float = 0.5
    c: float = 0.1
    d: float = 0.1
    e: float = 1.8
    g0: float = 2.0
    g1: float = 0.1


def linear_step(p: LinearParams, x, u):
    return jnp.asarray(p.A) @ x + jnp.asarray(p.B) @ jnp.reshape(u, (-1,))


def drift(p: NonlinearParams, x):
    """f(x) of §2.7.2."""
    x1, x2 = x[0], x[1]
    return jnp.stack([p.a * jnp.sin(p.w * x1) + p.c * x2, p.d * x1**2 + p.e * x2])


def input_gain(p: NonlinearParams, x):
    """g(x) of §2.7.2 (a column, returned as a length-2 vector)."""
    x2 = x[1]
    return jnp.stack([jnp.zeros_like(x2), p.g0 + p.g1 * jnp.cos(x2)])


def nonlinear_step(p: NonlinearParams, x, u):
    return drift(p, x) + input_gain(p, x) * jnp.reshape(u, (-1,))[0]


def linear() -> Plant:
    return Plant(
        name="example2d-linear",
        state_names=STATE_NAMES,
        input_names=("u",),
        default_params=LinearParams,
        step=linear_step,
    )


def nonlinear() -> Plant:
    return Plant(
        name="example2d-nonlinear",
        state_names=STATE_NAMES,
        input_names=("u",),
        default_params=NonlinearParams,
        step=nonlinear_step,
    )
