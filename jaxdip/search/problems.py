"""Transformations of an inverse problem that any ensemble Kalman step then solves unchanged.

* ``tikhonov(forward, y, R, prior_mean, prior_cov)``: Tikhonov-regularised EKI (TEKI, Chada, Stuart & Tong
  2020): the outputs are extended by the parameters themselves, G+(v) = (G(v), v), the data by the prior mean
  and the noise covariance by the prior covariance, so the search minimises
  |R^-1/2 (G(v) - y)|^2 + |C0^-1/2 (v - m0)|^2. On a linear map the minimiser is the posterior mean, and UKI's
  fixed point is the posterior.
* ``box(lower, upper)``: box constraints by transform (EnsembleKalmanProcesses.jl's constrained priors): the
  search runs over unconstrained u and the forward map sees x = lower + (upper - lower) sigmoid(u) (a bound
  left infinite: x = lower + exp(u), upper - exp(-u), or x = u), so every member is inside the box.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from jaxdip.engine.checks import fail
from jaxdip._public import public_dir

__all__ = ["tikhonov", "Box", "box"]
__dir__ = public_dir(globals())


def tikhonov(forward: Callable, y, R, prior_mean, prior_cov):
    """(forward+, y+, R+) of TEKI: ``forward+(points, key) = [forward(points, key), points]`` (outputs of the
    (J, p) points side by side), ``y+ = [y, prior_mean]``, ``R+ = blockdiag(R, prior_cov)``."""
    y, R = jnp.atleast_1d(jnp.asarray(y)), jnp.atleast_2d(jnp.asarray(R))
    m0, C0 = jnp.atleast_1d(jnp.asarray(prior_mean)), jnp.atleast_2d(jnp.asarray(prior_cov))
    if R.shape != (y.shape[0], y.shape[0]) or C0.shape != (m0.shape[0], m0.shape[0]):
        fail("tikhonov", f"R must be (m, m) for y of length m and prior_cov (p, p) for prior_mean of length p, "
                         f"got R {R.shape}, y {y.shape}, prior_cov {C0.shape}, prior_mean {m0.shape}")
    m, p = y.shape[0], m0.shape[0]
    R_plus = jnp.zeros((m + p, m + p), R.dtype).at[:m, :m].set(R).at[m:, m:].set(C0)

    def plus(points, key):
        Y = forward(points, key).reshape(points.shape[0], -1)
        return jnp.concatenate([Y, points], axis=1)

    return plus, jnp.concatenate([y, m0]), R_plus


class Box(NamedTuple):
    lower: jnp.ndarray
    upper: jnp.ndarray

    def to_constrained(self, u):
        """x(u) inside the box, entry by entry (u: (..., p))."""
        lo, hi = self.lower, self.upper
        both = lo + (hi - lo) * jax.nn.sigmoid(u)
        below = lo + jnp.exp(u)
        above = hi - jnp.exp(-u)
        fl, fh = jnp.isfinite(lo), jnp.isfinite(hi)
        return jnp.where(fl & fh, both, jnp.where(fl, below, jnp.where(fh, above, u)))

    def to_unconstrained(self, x):
        """u(x), the inverse of ``to_constrained`` (x strictly inside the box)."""
        lo, hi = self.lower, self.upper
        fl, fh = jnp.isfinite(lo), jnp.isfinite(hi)
        lo_s, hi_s = jnp.where(fl, lo, 0.0), jnp.where(fh, hi, 1.0)
        z = (x - lo_s) / jnp.where(fl & fh, hi_s - lo_s, 1.0)
        both = jnp.log(z) - jnp.log1p(-z)
        return jnp.where(fl & fh, both, jnp.where(fl, jnp.log(jnp.abs(x - lo_s)),
                                                  jnp.where(fh, -jnp.log(jnp.abs(hi_s - x)), x)))

    def wrap(self, forward: Callable) -> Callable:
        """``forward(points, key)`` over constrained points as a map of unconstrained ones."""
        return lambda points, key: forward(self.to_constrained(points), key)


def box(lower, upper) -> Box:
    """Bounds (scalars or (p,) arrays; ``-inf``/``inf`` for none) with lower < upper everywhere."""
    lo, hi = jnp.asarray(lower, dtype=float), jnp.asarray(upper, dtype=float)
    lo, hi = jnp.broadcast_arrays(lo, hi)
    if not bool(jnp.all(lo < hi)):
        fail("box", f"lower must be below upper in every entry, got lower {lower!r}, upper {upper!r}")
    return Box(lo, hi)
