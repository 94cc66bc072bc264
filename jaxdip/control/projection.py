"""Projection and relaxed projection control (thesis §2.3-2.5).

For x_{k+1} = f(x_k) + g(x_k) u and an SPD matrix P:

* projection (2.9):           u = -(g^T P g)^-1 g^T P f(x)
* relaxed, discrete (2.10):   u = -(g^T P g)^-1 g^T P (f(x) - x / (1 + gamma_k))
* relaxed, continuous (2.14): u = -(g^T P g)^-1 (gamma g^T P x + g^T P f(x))   for xdot = f(x) + g(x) u
* state-dependent weights (2.18): gamma_k = gamma / ||x_k||_2^alpha

For the controller's model of the plant (continuous or discrete), the drift is f(x, 0) and g(x) = df/du, by
autodiff: exact for the control-affine models here. ``linear_input=True`` uses g at the origin instead.

The linear closed form: for x_{k+1} = A x + B u under (2.16), with T = (I - Pi) A, Pi = B (B^T P B)^-1 B^T P
and c_k = 1/(1 + gamma_k), Pi T = 0 gives Pi x_k = (c_0 ... c_{k-1}) z_0 for z_0 = Pi x_0, hence

    x_k = T^k x_0 + sum_{m=0}^{k-1} (c_0 ... c_m) T^{k-1-m} z_0.

The thesis's (2.17) writes T^k v_0 (v_0 = x_0 - z_0) where this has T^k x_0 = T^k v_0 + T^k z_0; its induction
drops T^k z_0 (T z_0 = (I - Pi) A z_0 is not zero in general). ``relaxed_closed_form`` implements the form
derived here, and the tests check it against simulation.
"""

from __future__ import annotations

from typing import Any, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Controller, Plant, param, rhs


from jaxdip._public import public_dir

__all__ = ["projection", "relaxed_discrete", "relaxed_continuous", "state_weight", "drift_and_input",
           "RelaxedProjection", "projected_closed_loop", "relaxed_closed_form"]
__dir__ = public_dir(globals())


def _solve_gPg(P, g, rhs):
    g = g.reshape(P.shape[0], -1)
    gPg = g.T @ P @ g
    if gPg.shape == (1, 1):
        # one input: a division (a batched 1x1 LU is a LAPACK call per trajectory and period)
        return rhs / gPg[0]
    return jnp.linalg.solve(gPg, rhs)


def projection(P, fx, gx):
    """(2.9)."""
    gx = gx.reshape(P.shape[0], -1)
    return -_solve_gPg(P, gx, gx.T @ P @ fx)


def relaxed_discrete(P, fx, gx, x, gamma_k):
    """(2.10)."""
    gx = gx.reshape(P.shape[0], -1)
    return -_solve_gPg(P, gx, gx.T @ P @ (fx - x / (1.0 + gamma_k)))


def relaxed_continuous(P, fx, gx, x, gamma):
    """(2.14)."""
    gx = gx.reshape(P.shape[0], -1)
    return -_solve_gPg(P, gx, gamma * (gx.T @ P @ x) + gx.T @ P @ fx)


def state_weight(gamma, alpha, x, floor=None):
    """(2.18): gamma / ||x||^alpha; alpha = 0 gives a constant weight. Finite at x = 0 through the floor
    (default 1e-300, or the smallest normal number of a float32 x)."""
    if floor is None:
        floor = max(1e-300, float(jnp.finfo(jnp.result_type(x)).tiny))
    nx = jnp.maximum(jnp.linalg.norm(x), floor)
    return gamma / nx**alpha


def drift_and_input(plant_f, plant_params, x, m):
    """f(x) = plant_f(plant_params, x, 0) and g(x) = d plant_f / du at u = 0 (``m`` inputs)."""
    u0 = jnp.zeros(m, jnp.result_type(x))
    fx = plant_f(plant_params, x, u0)
    gx = jax.jacfwd(plant_f, argnums=2)(plant_params, x, u0)
    return fx, gx


def _model_map(model, x, u):
    # the controller's model as f(params, x, u) for drift_and_input; module-level, one function for jit
    return rhs(model, x, u) if model.continuous else model.step(x, u)


class RelaxedProjection(Controller):
    """The relaxed projection control as an engine controller: (2.14) (``kind="continuous"``) or (2.10)
    (``"discrete"``) with the state-dependent weight (2.18) gamma / ||x - x_ref||^alpha, or the projection
    (2.9) with ``projection_only``. ``model`` is the controller's model of the plant (an engine plant, which
    may differ from the simulated one); f(x) and g(x) come from it by autodiff at the estimate.

    Fields: the weight ``P``, gamma and alpha of (2.18) and the reference ``x_ref`` (zero when None) as arrays;
    the variant (``kind``, ``linear_input``, ``projection_only``) static.
    """

    model: Any
    P: jax.Array = param()
    gamma: jax.Array = param(0.0)
    alpha: jax.Array = param(0.0)
    x_ref: Optional[jax.Array] = None
    kind: str = eqx.field(default="continuous", static=True)
    linear_input: bool = eqx.field(default=False, static=True)
    projection_only: bool = eqx.field(default=False, static=True)

    def __check_init__(self):
        checks.check_choice(self, "kind", self.kind, ("continuous", "discrete"))
        if not isinstance(self.model, Plant):
            raise checks.ArgumentTypeError(f"RelaxedProjection: model must be a jaxdip Plant, "
                                           f"got {type(self.model).__name__}")
        n = self.model.n
        why = f"for the model {type(self.model).__name__} ({n} states)"
        # P is checked for its shape and finiteness only: published weights are symmetric to their printed digits
        checks.check_shape(self, "P", self.P, (n, n), why)
        checks.check_finite(self, "P", self.P)
        if self.x_ref is not None:
            checks.check_state_vector(self, "x_ref", self.x_ref, n, why)
        checks.check_nonnegative(self, "gamma", self.gamma)
        checks.check_nonnegative(self, "alpha", self.alpha)

    def io_sizes(self) -> dict:
        why = f"its model {type(self.model).__name__}"
        return {"in": (self.model.n, why), "out": (self.model.m, why)}

    def step(self, state, xhat, key, k):
        m = self.model
        x_ref = jnp.zeros(self.P.shape[0], xhat.dtype) if self.x_ref is None else self.x_ref
        x = xhat - x_ref
        fx, gx = drift_and_input(_model_map, m, xhat, m.m)
        if self.linear_input:
            gx = drift_and_input(_model_map, m, x_ref, m.m)[1]
        fx = fx - x_ref if not m.continuous else fx
        if self.projection_only:
            return state, projection(self.P, fx, gx), None
        g_k = state_weight(self.gamma, self.alpha, x)
        if self.kind == "continuous":
            return state, relaxed_continuous(self.P, fx, gx, x, g_k), None
        return state, relaxed_discrete(self.P, fx, gx, x, g_k), None


def projected_closed_loop(A, B, P):
    """T = (I - B (B^T P B)^-1 B^T P) A: the closed loop of linear projection control; P stabilises iff
    its spectral radius is below 1 (Definition 2.5.1)."""
    Pi = B @ jnp.linalg.solve(B.T @ P @ B, B.T @ P)
    return (jnp.eye(A.shape[0]) - Pi) @ A


def relaxed_closed_form(A, B, P, x0, gammas):
    """States x_1..x_K of x_{k+1} = A x + B u under (2.16), from the derived closed form (module docstring)."""
    B = B.reshape(A.shape[0], -1)
    Pi = B @ jnp.linalg.solve(B.T @ P @ B, B.T @ P)
    T = (jnp.eye(A.shape[0]) - Pi) @ A
    z0 = Pi @ x0
    c = 1.0 / (1.0 + jnp.asarray(gammas))
    cum = jnp.cumprod(c)  # c_0 ... c_m
    K = c.shape[0]
    Tpows = [jnp.eye(A.shape[0])]
    for _ in range(K):
        Tpows.append(T @ Tpows[-1])
    out = []
    for k in range(1, K + 1):
        xk = Tpows[k] @ x0
        for m in range(k):
            xk = xk + cum[m] * (Tpows[k - 1 - m] @ z0)
        out.append(xk)
    return jnp.stack(out)
