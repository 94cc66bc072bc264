"""Localisers: corrections of the sample covariances an ensemble Kalman update uses, for small ensembles.

With J members and p parameters, the sample cross-covariance C_vy carries spurious correlations of order
1 / sqrt(J) between every parameter and every output; with p >> J they dominate the update. A localiser is a
function ``localise(Cvy, Cyy, var_v, J) -> (Cvy, Cyy)`` (``var_v``: the (p,) sample variances of the
parameters, for correlations), applied before the gain is formed. Two kinds:

* ``schur(kernel_vy, kernel_yy)``: the Schur (entrywise) products of C_vy with a (p, m) kernel and of C_yy with an
  (m, m) one, e.g. ``distance_kernel`` of the parameters' and the outputs' positions (Gaspari-Cohn or Gaussian
  taper), or the identity for outputs that observe one parameter each (EnsembleKalmanProcesses.jl's
  ``Delta``). Localise C_yy too when the step is large: a tapered C_vy has components outside the ensemble's
  span, which (C_yy + R / dt)^-1 amplifies by dt / R where the rank-(J - 1) C_yy is zero;
* sampling-error correction, which needs no positions: ``sec(alpha, r0)`` shrinks every correlation r to
  r |r|^alpha and cuts those below r0 (Lee 2021); ``sec_fisher()`` shrinks r by Q^2 / (1 + Q^2), Q = r / sigma_r,
  sigma_r its sampling spread for J members from the Fisher transform (Flowerdew 2015, as used by Lee 2021).
  Both act on the C_vy and C_yy blocks (the diagonal of C_yy is kept).
"""

from __future__ import annotations

from typing import Callable

import jax.numpy as jnp

from jaxdip.engine.checks import check_choice, check_nonnegative, check_positive
from jaxdip._public import public_dir

__all__ = ["Localiser", "schur", "distance_kernel", "sec", "sec_fisher"]
__dir__ = public_dir(globals())

Localiser = Callable  # (Cvy (p, m), Cyy (m, m), var_v (p,), J) -> (Cvy, Cyy)


def schur(kernel_vy, kernel_yy=None) -> Localiser:
    """C_vy multiplied entrywise by ``kernel_vy`` (p, m), and C_yy by ``kernel_yy`` (m, m; None: kept)."""
    kvy = jnp.asarray(kernel_vy)
    kyy = None if kernel_yy is None else jnp.asarray(kernel_yy)
    return lambda Cvy, Cyy, var_v, J: (Cvy * kvy, Cyy if kyy is None else Cyy * kyy)


def distance_kernel(positions_v, positions_y, length: float, shape: str = "gaspari_cohn") -> jnp.ndarray:
    """(p, m) taper of the distances between parameter i at ``positions_v[i]`` and output j at
    ``positions_y[j]`` (scalars or vectors): Gaspari-Cohn's compactly supported fifth-order function (zero
    beyond 2 * ``length``) or a Gaussian exp(-d^2 / (2 length^2))."""
    check_positive("distance_kernel", "length", length)
    check_choice("distance_kernel", "shape", shape, ("gaspari_cohn", "gaussian"))
    a = jnp.asarray(positions_v, dtype=float).reshape(len(positions_v), -1)
    b = jnp.asarray(positions_y, dtype=float).reshape(len(positions_y), -1)
    d = jnp.sqrt(jnp.sum((a[:, None, :] - b[None, :, :]) ** 2, axis=-1))
    if shape == "gaussian":
        return jnp.exp(-0.5 * (d / length) ** 2)
    r = d / length
    near = -0.25 * r**5 + 0.5 * r**4 + 0.625 * r**3 - 5.0 / 3.0 * r**2 + 1.0
    far = r**5 / 12.0 - 0.5 * r**4 + 0.625 * r**3 + 5.0 / 3.0 * r**2 - 5.0 * r + 4.0 - 2.0 / (3.0 * jnp.maximum(r, 1e-300))
    return jnp.where(r <= 1.0, near, jnp.where(r < 2.0, far, 0.0))


def _blocks(Cvy, Cyy, var_v, shrink):
    # correlations of the (v, y) and (y, y) blocks, shrunk, and scaled back to covariances
    sv = jnp.sqrt(jnp.maximum(var_v, 1e-300))
    sy = jnp.sqrt(jnp.maximum(jnp.diag(Cyy), 1e-300))
    Rvy = Cvy / (sv[:, None] * sy[None, :])
    Ryy = Cyy / (sy[:, None] * sy[None, :])
    Ryy_s = jnp.where(jnp.eye(Cyy.shape[0], dtype=bool), Ryy, shrink(Ryy))
    return shrink(Rvy) * sv[:, None] * sy[None, :], Ryy_s * sy[:, None] * sy[None, :]


def sec(alpha: float = 1.0, r0: float = 0.0) -> Localiser:
    """Sampling-error correction of Lee (2021): r -> r |r|^alpha, then 0 where |r |r|^alpha| <= r0."""
    check_nonnegative("sec", "alpha", alpha)
    check_nonnegative("sec", "r0", r0)

    def shrink(R):
        Rs = R * jnp.abs(R) ** alpha
        return jnp.where(jnp.abs(Rs) > r0, Rs, 0.0)

    return lambda Cvy, Cyy, var_v, J: _blocks(Cvy, Cyy, var_v, shrink)


def sec_fisher() -> Localiser:
    """Sampling-error correction from the Fisher transform (Flowerdew 2015): r -> r Q^2 / (1 + Q^2) with
    Q = r / sigma_r, sigma_r = (tanh(atanh r + s) - tanh(atanh r - s)) / 2, s = 1 / sqrt(J - 3)."""

    def localise(Cvy, Cyy, var_v, J):
        s = 1.0 / jnp.sqrt(jnp.maximum(J - 3.0, 1.0))

        def shrink(R):
            r = jnp.clip(R, -1 + 1e-12, 1 - 1e-12)
            z = jnp.arctanh(r)
            sigma = 0.5 * (jnp.tanh(z + s) - jnp.tanh(z - s))
            Q2 = (r / sigma) ** 2
            return r * Q2 / (1.0 + Q2)

        return _blocks(Cvy, Cyy, var_v, shrink)

    return localise
