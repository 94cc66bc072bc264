"""Argument checks for the public constructors and functions, so a mistake is reported where it is made.

Every check raises ``ArgumentError`` (a ``ValueError``; ``ArgumentTypeError``, also a ``TypeError``, for a
wrong dtype) with one message of the form ``"<owner>: <argument> must be <expected>, got <what it got>"``, e.g.
``KalmanFilter: Q must be (6, 6) for a 6-state model, got (4, 4)``. ``owner`` is the class or the function.

Checks run on concrete values only. Inside ``jit``, ``vmap`` or ``grad`` a field may be a tracer: shapes are
still known and checked, values are not (a tracer has none), so a vmapped sweep over a gain or ``jax.grad``
through a weight builds its components as it did before these checks existed. Values are read on the host
(NumPy), never changed: a check returns nothing and alters no number.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import jax
import numpy as np

from jaxdip._public import public_dir

__all__ = ["ArgumentError", "ArgumentTypeError", "owner_name", "fail", "is_concrete", "shape_of", "fmt_shape", "check_real", "check_shape", "check_ndim", "check_square", "check_finite", "check_positive", "check_nonnegative", "check_psd", "check_int", "check_choice", "check_covariance", "check_state_vector", "check_scalar_or_vector", "check_limits", "check_physical", "check_lti"]
__dir__ = public_dir(globals())

# Symmetry and definiteness are judged to rounding: a covariance computed as A A^T or assembled from a
# config is symmetric to ~1e-16 relative (an inverse of an ill-conditioned one to ~1e-10), so 1e-6 relative
# never rejects one built honestly and still catches a matrix that is not symmetric at all.
_SYM_RTOL = 1e-6
_EIG_RTOL = 1e-12


class ArgumentError(ValueError):
    """A public constructor or function was given an argument of the wrong shape or value."""


class ArgumentTypeError(ArgumentError, TypeError):
    """An argument of the wrong type or dtype (a string, a complex number, an object where numbers go)."""


def owner_name(owner: Any) -> str:
    """``owner`` as the message names it: a string as is, a class or instance by its class name."""
    if isinstance(owner, str):
        return owner
    return owner.__name__ if isinstance(owner, type) else type(owner).__name__


def fail(owner: Any, message: str) -> None:
    raise ArgumentError(f"{owner_name(owner)}: {message}")


def is_concrete(*values: Any) -> bool:
    """True when no leaf of ``values`` is a tracer (the values can be read on the host)."""
    return not any(isinstance(leaf, jax.core.Tracer) for v in values for leaf in jax.tree_util.tree_leaves(v))


def shape_of(value: Any) -> tuple:
    """The shape of an array, tracer, number or nested list (no copy to the host)."""
    shape = getattr(value, "shape", None)
    if shape is not None:
        return tuple(shape)
    return np.shape(value)


def fmt_shape(shape: Sequence[Optional[int]]) -> str:
    s = ", ".join("*" if d is None else str(d) for d in shape)
    return f"({s},)" if len(shape) == 1 else f"({s})"


def check_real(owner: Any, name: str, value: Any) -> None:
    """``value`` holds real numbers (bool, int or float dtype): not strings, objects or complex numbers."""
    dtype = getattr(value, "dtype", None)
    if dtype is None:
        try:
            dtype = np.asarray(value).dtype
        except (TypeError, ValueError):
            dtype = np.dtype(object)
    if np.dtype(dtype).kind not in "biuf":
        what = np.dtype(dtype).name if np.dtype(dtype).kind == "c" else type(value).__name__
        if np.dtype(dtype).kind in "OSU" and not hasattr(value, "dtype"):
            what = repr(value) if len(repr(value)) <= 40 else type(value).__name__
        raise ArgumentTypeError(f"{owner_name(owner)}: {name} must be real numbers, got {what}")


def check_shape(owner: Any, name: str, value: Any, shape: Sequence[Optional[int]], why: str = "",
                leading: bool = False) -> tuple:
    """``value`` has ``shape`` (``None``: any size there). ``leading``: extra leading axes are allowed (a stack
    over time). ``why`` is appended to the expectation ("for a 6-state model"). Returns the shape."""
    got = shape_of(value)
    tail = got[len(got) - len(shape):] if leading and len(got) >= len(shape) else got
    ok = len(tail) == len(shape) and all(e is None or e == g for e, g in zip(shape, tail))
    if not ok:
        expected = fmt_shape(shape) + (" (or a stack of them over time)" if leading and len(got) > len(shape) else "")
        fail(owner, f"{name} must be {expected}{' ' + why if why else ''}, got {fmt_shape(got)}")
    return got


def check_ndim(owner: Any, name: str, value: Any, ndims: Sequence[int], what: str) -> tuple:
    """``value`` has one of ``ndims`` axes; ``what`` describes them ("a scalar or a vector")."""
    got = shape_of(value)
    if len(got) not in ndims:
        fail(owner, f"{name} must be {what}, got shape {fmt_shape(got)}")
    return got


def check_square(owner: Any, name: str, value: Any, n: Optional[int] = None, why: str = "",
                 leading: bool = False) -> int:
    """``value`` is an n x n matrix (any n when ``n`` is None); returns n."""
    got = shape_of(value)
    if n is None:
        if len(got) < 2 or got[-1] != got[-2] or (len(got) > 2 and not leading):
            fail(owner, f"{name} must be a square matrix{' ' + why if why else ''}, got shape {fmt_shape(got)}")
        return got[-1]
    check_shape(owner, name, value, (n, n), why, leading)
    return n


def _host(value: Any) -> Optional[np.ndarray]:
    """The value as a float NumPy array, or None for a tracer (no value to check)."""
    if not is_concrete(value):
        return None
    return np.asarray(value, dtype=np.float64)


def check_finite(owner: Any, name: str, value: Any) -> None:
    a = _host(value)
    if a is not None and not np.all(np.isfinite(a)):
        fail(owner, f"{name} must be finite, got {_first_bad(a, ~np.isfinite(a))}")


def check_positive(owner: Any, name: str, value: Any, allow_inf: bool = False) -> None:
    """Every entry > 0 (and finite unless ``allow_inf``)."""
    a = _host(value)
    if a is None:
        return
    bad = ~(a > 0) | (~np.isfinite(a) if not allow_inf else np.isnan(a))
    if np.any(bad):
        fail(owner, f"{name} must be positive{'' if allow_inf else ' and finite'}, got {_first_bad(a, bad)}")


def check_nonnegative(owner: Any, name: str, value: Any, allow_inf: bool = False) -> None:
    """Every entry >= 0 (noise levels, dead bands); finite unless ``allow_inf``."""
    a = _host(value)
    if a is None:
        return
    bad = ~(a >= 0) | (~np.isfinite(a) if not allow_inf else np.isnan(a))
    if np.any(bad):
        fail(owner, f"{name} must be >= 0{'' if allow_inf else ' and finite'}, got {_first_bad(a, bad)}")


def check_psd(owner: Any, name: str, value: Any, definite: bool = False) -> None:
    """A symmetric positive semidefinite matrix (``definite``: positive definite), or a stack of them."""
    a = _host(value)
    if a is None:
        return
    kind = "positive definite" if definite else "positive semidefinite"
    if not np.all(np.isfinite(a)):
        fail(owner, f"{name} must be finite, got {_first_bad(a, ~np.isfinite(a))}")
    scale = max(float(np.max(np.abs(a), initial=0.0)), np.finfo(float).tiny)
    asym = float(np.max(np.abs(a - np.swapaxes(a, -1, -2)), initial=0.0))
    if asym > _SYM_RTOL * scale:
        fail(owner, f"{name} must be symmetric {kind}, got an asymmetry of {asym:.3g} (largest entry {scale:.3g})")
    w = np.linalg.eigvalsh(a)
    lo = float(np.min(w))
    tol = _EIG_RTOL * scale
    if (definite and lo <= tol) or (not definite and lo < -tol):
        fail(owner, f"{name} must be symmetric {kind}, got smallest eigenvalue {lo:.3g}")


def check_int(owner: Any, name: str, value: Any, minimum: Optional[int] = None) -> None:
    """A Python (or NumPy) integer, at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ArgumentTypeError(f"{owner_name(owner)}: {name} must be an integer, got {value!r}")
    if minimum is not None and value < minimum:
        fail(owner, f"{name} must be >= {minimum}, got {value}")


def check_choice(owner: Any, name: str, value: Any, choices: Sequence[Any]) -> None:
    if value not in choices:
        fail(owner, f"{name} must be one of {tuple(choices)}, got {value!r}")


def check_covariance(owner: Any, name: str, value: Any, n: int, why: str = "", leading: bool = False,
                     definite: bool = False) -> None:
    """An n x n symmetric positive semidefinite matrix (or a stack of them, with ``leading``)."""
    check_shape(owner, name, value, (n, n), why, leading)
    check_psd(owner, name, value, definite)


def check_state_vector(owner: Any, name: str, value: Any, n: int, why: str = "") -> None:
    """A finite vector of n entries (an initial estimate)."""
    check_shape(owner, name, value, (n,), why)
    check_finite(owner, name, value)


def check_scalar_or_vector(owner: Any, name: str, value: Any, n: Optional[int] = None, why: str = "") -> None:
    """A scalar, or a vector (of n entries when n is given): a noise level per channel or one for all."""
    got = shape_of(value)
    if got == () or (len(got) == 1 and (n is None or got[0] == n)):
        return
    expected = "a scalar or a vector" if n is None else f"a scalar or ({n},)"
    fail(owner, f"{name} must be {expected}{' ' + why if why else ''}, got shape {fmt_shape(got)}")


def check_limits(owner, lo_name: str, lo, hi_name: str, hi) -> None:
    """A pair of bounds (scalars or one per input, of the same size), lo <= hi, not NaN."""
    for name, v in ((lo_name, lo), (hi_name, hi)):
        check_scalar_or_vector(owner, name, v, why="(one for every input, or one per input)")
    a, b = shape_of(lo), shape_of(hi)
    if a and b and a != b:
        fail(owner, f"{hi_name} must have the shape of {lo_name} {fmt_shape(a)}, "
                    f"got {fmt_shape(b)}")
    if is_concrete(lo, hi):
        lo_h, hi_h = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        if np.any(np.isnan(lo_h)) or np.any(np.isnan(hi_h)):
            fail(owner, f"{lo_name} and {hi_name} must not be NaN, got {lo_h} and {hi_h}")
        if np.any(lo_h > hi_h):
            fail(owner, f"{lo_name} must be <= {hi_name}, got {lo_name}={lo_h} > {hi_name}={hi_h}")


def check_physical(owner: Any, positive: Sequence[str] = (), nonnegative: Sequence[str] = (),
                   finite: Sequence[str] = ()) -> None:
    """A plant's constants by field name: masses, lengths, inertias > 0; dampings >= 0; anything finite."""
    for name in positive:
        check_positive(owner, name, getattr(owner, name))
    for name in nonnegative:
        check_nonnegative(owner, name, getattr(owner, name))
    for name in finite:
        check_finite(owner, name, getattr(owner, name))


def check_lti(owner: Any, Phi: Any, W: Any, C: Any = None, Phi_inv: Any = None, prefix: str = "") -> tuple:
    """A discrete LTI model: Phi (d, d), W (d, m), C (p, d), Phi_inv (d, d), finite; returns (d, m, p).
    ``prefix`` names where the matrices sit ("model." for a ``Discrete`` argument)."""
    d = check_square(owner, prefix + "Phi", Phi)
    why = f"for a {d}-state model (Phi is {fmt_shape(shape_of(Phi))})"
    check_shape(owner, prefix + "W", W, (d, None), why)
    m = shape_of(W)[1]
    p = None
    if Phi_inv is not None:
        check_shape(owner, prefix + "Phi_inv", Phi_inv, (d, d), why)
    if C is not None:
        check_shape(owner, "C", C, (None, d), why)
        p = shape_of(C)[0]
    for name, v in ((prefix + "Phi", Phi), (prefix + "W", W), ("C", C), (prefix + "Phi_inv", Phi_inv)):
        if v is not None:
            check_finite(owner, name, v)
    return d, m, p


def _first_bad(a: np.ndarray, bad: np.ndarray) -> str:
    if a.ndim == 0:
        return f"{a.item():.6g}"
    i = tuple(int(j) for j in np.argwhere(bad)[0])
    where = i[0] if len(i) == 1 else i
    return f"{a[i]:.6g} at index {where}"
