"""Weight matrices given in a config: n diagonal entries or an n x n symmetric positive semi-definite matrix."""

from __future__ import annotations

import numpy as np

from jaxdip.config import ConfigError


def weight_matrix(key: str, value, n: int) -> np.ndarray:
    """A weight given as n diagonal entries or an n x n symmetric PSD matrix."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape == (n,):
        arr = np.diag(arr)
    elif arr.shape != (n, n):
        raise ConfigError(key, f"must be {n} diagonal weights or a {n}x{n} matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(key, "must be finite")
    if not np.allclose(arr, arr.T):
        raise ConfigError(key, "must be symmetric")
    if np.linalg.eigvalsh(arr).min() < -1e-12 * max(1.0, np.abs(arr).max()):
        raise ConfigError(key, "must be positive semi-definite")
    return arr
