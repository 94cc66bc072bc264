"""The linear-Gaussian model of a ``KalmanFilter`` laid out for the square-root and parallel forms of
``jaxdip.estimators.recorded``, with missing measurements removed.

Missing data. A missing component of y_k is removed exactly by zeroing its row of C_k, its residual and its
off-diagonal entries of R_k and putting 1 on its diagonal of R_k: the component then reads pure unit noise with
value 0, independent of everything, so it changes no moment and contributes log N(0; 0, 1) = -0.5 log(2 pi) to
log p(y_k | y_0..k-1), which is added back.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp

from jaxdip.engine import checks

_HALF_LOG_2PI = 0.9189385332046727


class LinearGaussian(NamedTuple):
    """Every matrix is either time-invariant (2-D) or a stack over time (leading axis T, ``at``)."""

    Phi: jax.Array  # drives x_j -> x_{j+1}, with W, Q
    W: jax.Array
    Q: jax.Array
    C: jax.Array  # reads y_j, with R
    R: jax.Array
    P0: jax.Array
    xhat0: jax.Array
    ys: jax.Array  # (T, p), missing components set to 0
    us: jax.Array  # (T, m): us[j] drives x_j -> x_{j+1}
    ll_offset: jax.Array  # (T,) 0.5 log(2 pi) per missing component of y_j


def at(a, j):
    """A time-invariant matrix, or entry j of a stack over time."""
    return a if a.ndim == 2 else a[j]


def stacked(a, T: int):
    """``a`` as a stack over time (T, ...)."""
    return jnp.broadcast_to(a, (T,) + a.shape) if a.ndim == 2 else a


def resolve_mask(owner, ys, mask, nan_missing: bool) -> Optional[jax.Array]:
    """The (T, p) boolean mask (True = observed) from ``mask`` (None, (T,) or (T, p)) and, with
    ``nan_missing``, the NaN entries of ``ys``; None when everything is observed."""
    T, p = ys.shape
    if mask is not None:
        checks.check_ndim(owner, "mask", mask, (1, 2), "a boolean (T,) or (T, p) array, True = observed")
        mask = jnp.asarray(mask)
        if mask.dtype != jnp.bool_:
            raise checks.ArgumentTypeError(f"{checks.owner_name(owner)}: mask must be boolean (True = observed), "
                                           f"got {mask.dtype}")
        checks.check_shape(owner, "mask", mask, (T,) if mask.ndim == 1 else (T, p), f"for ys of shape {(T, p)}")
        mask = jnp.broadcast_to(mask[:, None] if mask.ndim == 1 else mask, (T, p))
    if nan_missing:
        seen = ~jnp.isnan(ys)
        mask = seen if mask is None else mask & seen
    return mask


def linear_gaussian(owner, kf, ys, us, mask=None, nan_missing: bool = False) -> LinearGaussian:
    """The model of ``kf`` (a ``KalmanFilter``) over ``ys`` (T, p), ``us`` (T, m) or None, in the dtype of
    ``jnp.result_type(float)``."""
    from jaxdip.estimators.kf import KalmanFilter  # kf imports this package's kernel; keep the import local

    if not isinstance(kf, KalmanFilter):
        raise checks.ArgumentTypeError(f"{checks.owner_name(owner)}: the square-root and parallel forms need a "
                                       f"KalmanFilter (a linear-Gaussian model), got {type(kf).__name__}")
    dt = jnp.result_type(float)
    ys = jnp.asarray(ys, dt)
    checks.check_shape(owner, "ys", ys, (None, kf.C.shape[-2]), f"for {kf.C.shape[-2]} measurements")
    T = ys.shape[0]
    us = jnp.zeros((T, kf.n_inputs), dt) if us is None else jnp.asarray(us, dt).reshape(T, -1)
    mats = [jnp.asarray(getattr(kf, n), dt) for n in ("Phi", "W", "Q", "C", "R", "P0", "xhat0")]
    mask = resolve_mask(owner, ys, mask, nan_missing)
    if mask is None:
        return LinearGaussian(*mats, ys, us, jnp.zeros(T, dt))
    Phi, W, Q, C, R, P0, xhat0 = mats
    C = jnp.where(mask[:, :, None], stacked(C, T), 0.0)
    both = mask[:, :, None] & mask[:, None, :]
    R = jnp.where(both, stacked(R, T), 0.0) + jax.vmap(jnp.diag)((~mask).astype(dt))
    ys = jnp.where(mask, ys, 0.0)
    offset = _HALF_LOG_2PI * jnp.sum(~mask, axis=1).astype(dt)
    return LinearGaussian(Phi, W, Q, C, R, P0, xhat0, ys, us, offset)


def psd_factor(A):
    """A square root L of a symmetric positive semidefinite A (L L^T = A): the lower Cholesky factor, or, when
    that is not finite (A singular), the symmetric root from the eigendecomposition."""
    n = A.shape[-1]
    bad = ~jnp.all(jnp.isfinite(jnp.linalg.cholesky(jax.lax.stop_gradient(A))))
    eye = jnp.eye(n, dtype=A.dtype)
    L = jnp.linalg.cholesky(jnp.where(bad, eye, A))
    # distinct eigenvalues in the unselected branch keep the eigh derivative (1 / (l_i - l_j)) finite
    w, V = jnp.linalg.eigh(jnp.where(bad, A, jnp.diag(jnp.arange(1, n + 1, dtype=A.dtype))))
    return jnp.where(bad, V * jnp.sqrt(jnp.maximum(w, 0.0)), L)
