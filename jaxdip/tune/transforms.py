"""Constrained hyperparameters, tuned in an unconstrained space (the dynamax habit, as bijectors per leaf).

A *spec* is a pytree shaped like the hyperparameters whose leaves are transforms: ``Unconstrained()``, ``Log()``
(positive scalars or arrays, theta = exp(u)), ``Softplus()`` (positive, theta = softplus(u), gentler for values
that may approach 0), ``Bounded(lo, hi)`` (theta = lo + (hi - lo) sigmoid(u)) and ``SPDFactor()`` (an SPD matrix
theta = L L^T + eps I with L lower-triangular, its diagonal through exp). ``to_unconstrained(spec, theta)`` and
``to_constrained(spec, u)`` are exact inverses of each other (up to rounding) on the constrained set.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


from jaxdip._public import public_dir

__all__ = ["Transform", "Unconstrained", "Log", "Softplus", "Bounded", "SPDFactor", "to_constrained",
           "to_unconstrained", "unconstrained_spec"]
__dir__ = public_dir(globals())


class Transform:
    def forward(self, u):  # unconstrained -> constrained
        raise NotImplementedError

    def inverse(self, theta):  # constrained -> unconstrained
        raise NotImplementedError

    def __repr__(self):
        return type(self).__name__ + "()"


class Unconstrained(Transform):
    """Real values, any sign: theta = u (the identity map; not ``jd.Identity``, the engine's identity role)."""

    def forward(self, u):
        return u

    def inverse(self, theta):
        return jnp.asarray(theta, dtype=jnp.result_type(float))


class Log(Transform):
    """Positive values: theta = exp(u). Steps in u are relative steps in theta."""

    def forward(self, u):
        return jnp.exp(u)

    def inverse(self, theta):
        theta = jnp.asarray(theta, dtype=jnp.result_type(float))
        return jnp.log(theta)


class Softplus(Transform):
    """Positive values: theta = log(1 + exp(u))."""

    def forward(self, u):
        return jax.nn.softplus(u)

    def inverse(self, theta):
        theta = jnp.asarray(theta, dtype=jnp.result_type(float))
        return theta + jnp.log(-jnp.expm1(-theta))


class Bounded(Transform):
    """Values in (lo, hi): theta = lo + (hi - lo) sigmoid(u)."""

    def __init__(self, lo, hi):
        if not hi > lo:
            raise ValueError(f"Bounded needs hi > lo, got ({lo}, {hi})")
        self.lo, self.hi = float(lo), float(hi)

    def forward(self, u):
        return self.lo + (self.hi - self.lo) * jax.nn.sigmoid(u)

    def inverse(self, theta):
        s = (jnp.asarray(theta, dtype=jnp.result_type(float)) - self.lo) / (self.hi - self.lo)
        return jnp.log(s) - jnp.log1p(-s)

    def __repr__(self):
        return f"Bounded({self.lo}, {self.hi})"


class SPDFactor(Transform):
    """SPD matrices: theta = L L^T + eps I, L lower-triangular with diagonal exp(u_ii); u is a full n x n array
    whose strict upper triangle is ignored."""

    def __init__(self, eps: float = 0.0):
        self.eps = float(eps)

    def forward(self, u):
        n = u.shape[-1]
        L = jnp.tril(u, -1) + jnp.diag(jnp.exp(jnp.diag(u)))
        return L @ L.T + self.eps * jnp.eye(n, dtype=u.dtype)

    def inverse(self, theta):
        theta = jnp.asarray(theta, dtype=jnp.result_type(float))
        n = theta.shape[-1]
        L = jnp.linalg.cholesky(theta - self.eps * jnp.eye(n, dtype=theta.dtype))
        return jnp.tril(L, -1) + jnp.diag(jnp.log(jnp.diag(L)))

    def __repr__(self):
        return f"SPDFactor(eps={self.eps})"


def _is_tf(x):
    return isinstance(x, Transform)


def to_constrained(spec, u):
    return jax.tree_util.tree_map(lambda t, x: t.forward(x), spec, u, is_leaf=_is_tf)


def to_unconstrained(spec, theta):
    return jax.tree_util.tree_map(lambda t, x: t.inverse(x), spec, theta, is_leaf=_is_tf)


def unconstrained_spec(theta):
    """A spec of ``Unconstrained()`` for every leaf of ``theta``: tuning in theta's own coordinates."""
    return jax.tree_util.tree_map(lambda _: Unconstrained(), theta)
