"""Local affine models of nonlinear continuous dynamics, for the linearised estimators (thesis §1.6).

At a reference point (xbar, ubar) the dynamics xdot = f(x, u) are replaced by their first-order expansion

    xdot = f(xbar, ubar) + A (x - xbar) + B (u - ubar),   A = df/dx, B = df/du at (xbar, ubar),

and this affine ODE is solved exactly over one sample period h with the input held:

    x(h) = xbar + Phi (x(0) - xbar) + W (u - ubar) + w,
    Phi = e^{A h},  W = int_0^h e^{A s} ds B,  w = int_0^h e^{A s} ds f(xbar, ubar),

all three from one matrix exponential of [[A, B, f(xbar, ubar)], [0, 0, 0]] h (as ``jaxdip.sim.discretize.zoh``),
and Phi^{-1} = e^{-A h} from a second one (the thesis's "forward map and backward map by expm").

Written as an LTI step with an offset, x_{k+1} = Phi x_k + W u_k + b with b = xbar - Phi xbar - W ubar + w.
Why the offset: the thesis writes the propagation as xhat_{k+1} = Phi_k p_k. For a nonlinear f that drops
f(xbar) - A xbar, which is not small (for the Lorenz system A(x) x - f(x) = (0, -x z, x y), hundreds of units
per time unit). With the offset the model is the exponential-Euler step at xbar: exact for linear f, and on the
Lorenz attractor at h = 0.001 within 6e-6 of the true flow per step.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp



from jaxdip._public import public_dir

__all__ = ["AffineStep", "lti_step", "expm_small", "local_model"]
__dir__ = public_dir(globals())


class AffineStep(NamedTuple):
    """x_{k+1} = Phi x_k + W u_k + b  and  x_k = Phi_inv (x_{k+1} - W u_k - b)."""

    Phi: jnp.ndarray
    Phi_inv: jnp.ndarray
    W: jnp.ndarray
    b: jnp.ndarray


def lti_step(Phi, Phi_inv, W) -> AffineStep:
    return AffineStep(Phi, Phi_inv, W, jnp.zeros(Phi.shape[0], Phi.dtype))


def expm_small(M, order: int = 12, theta: float = 0.25, max_squarings: int = 24):
    """e^M by scaling and squaring with a Taylor polynomial: only matrix products, so it vectorises under vmap.

    ``jax.scipy.linalg.expm`` (Pade with a linear solve, several degree branches) lowers to one LAPACK call
    per batch item and evaluates every branch under vmap; for the small matrices of the estimators this
    version is several times faster. M is scaled by 2^-s with s = ceil(log2(||M||_1 / theta)) clipped to
    [0, max_squarings], so ||M / 2^s||_1 <= theta = 0.25 and the truncation error of the degree-12 Taylor
    polynomial is below theta^13/13! ~ 2e-18 relative; the s squarings are done as ``max_squarings`` masked
    products (a fixed trip count keeps it reverse-differentiable). Matrices with ||M||_1 > theta 2^max_squarings
    are beyond its accuracy: the default 24 covers ||M||_1 <= 4e6; a caller that knows its scale (the Lorenz
    experiment: ||[A, f] h||_1 < 0.7 on the attractor) passes fewer, each squaring costs one product per call.
    """
    n = M.shape[-1]
    norm = jnp.max(jnp.sum(jnp.abs(M), axis=-2))
    s = jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-300) / theta))
    s = jnp.clip(jnp.where(jnp.isfinite(s), s, 0.0), 0, max_squarings).astype(jnp.int32)
    X = M / jnp.asarray(2.0, M.dtype) ** s
    eye = jnp.eye(n, dtype=M.dtype)
    E = eye
    for j in range(order, 0, -1):  # Horner: I + X/1 (I + X/2 (I + ... (I + X/order)))
        E = eye + (X @ E) / j
    if max_squarings == 0:
        return E
    return jax.lax.fori_loop(0, max_squarings, lambda i, E: jnp.where(i < s, E @ E, E), E)


def local_model(f: Callable, model_params, xbar, ubar, h, with_inverse: bool = True,
                max_squarings: int = 24) -> AffineStep:
    """Exact ZOH discretisation over h of the linearisation of ``f(model_params, x, u)`` at (xbar, ubar).

    One exponential of the augmented matrix [[A, B, f(xbar, ubar)], [0, 0, 0]] h gives Phi, W and w; a second
    one, e^{-A h}, gives Phi^{-1} (``with_inverse=False`` skips it and leaves NaN: the EKF needs only Phi).

    A program of its own, traced once per ``f``, model structure and shapes: the estimators of one loop (an EKF
    and the CPX variants beside it) and every trace of a loop take the same linearisation, 0.1 s of tracing each
    time otherwise; XLA inlines it, so the compiled code is the same.
    """
    return _local_model(f, model_params, xbar, ubar, h, with_inverse, max_squarings)


@eqx.filter_jit
def _local_model(f, model_params, xbar, ubar, h, with_inverse, max_squarings) -> AffineStep:
    xbar = jnp.asarray(xbar)
    ubar = jnp.atleast_1d(jnp.asarray(ubar, dtype=xbar.dtype))
    fx = lambda x: f(model_params, x, ubar)  # noqa: E731
    c, A = fx(xbar), jax.jacfwd(fx)(xbar)
    B = jax.jacfwd(lambda u: f(model_params, xbar, u))(ubar).reshape(xbar.shape[0], ubar.shape[0])
    Bc = jnp.concatenate([B, c[:, None]], axis=1)
    n, mc = Bc.shape
    M = jnp.zeros((n + mc, n + mc), A.dtype).at[:n, :n].set(A).at[:n, n:].set(Bc)
    E = expm_small(M * h, max_squarings=max_squarings)
    Phi, Wc = E[:n, :n], E[:n, n:]
    Phi_inv = expm_small(-A * h, max_squarings=max_squarings) if with_inverse else jnp.full((n, n), jnp.nan, A.dtype)
    m = ubar.shape[0]
    W, w = Wc[:, :m], Wc[:, m]
    b = xbar - Phi @ xbar - W @ ubar + w
    return AffineStep(Phi, Phi_inv, W, b)
