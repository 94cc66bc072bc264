"""Results of deterministic array functions kept by the values of their arguments.

A design or a quadrature called again with arguments equal to an earlier call's (equal values, not only equal
shapes) returns that call's result instead of computing it again: an experiment's configurations rebuild the same
LQR design for every case they run, and its searches meet the same sets more than once. The key is the arguments'
tree structure (with its static fields) and every leaf's dtype, shape and bytes, so two calls share a result only
where the function could not tell them apart; a traced argument (inside ``jit``, ``vmap`` or a gradient) or a
leaf that is not an array or a number skips the memo and calls the function.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

import jax
import numpy as np

from jaxdip._public import public_dir

__all__ = ["value_key", "memoised"]
__dir__ = public_dir(globals())


def value_key(args: Any) -> tuple | None:
    """``args`` as a hashable value (tree structure with its static fields, and every leaf's dtype, shape and
    bytes), or None when a leaf is traced (no value to key on) or is not an array or a number."""
    leaves, treedef = jax.tree_util.tree_flatten(args)
    if not all(isinstance(leaf, (jax.Array, np.ndarray, np.generic, int, float, bool)) for leaf in leaves):
        return None
    if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        return None
    parts = []
    for leaf in leaves:
        a = np.asarray(leaf)
        parts.append((a.dtype.str, a.shape, a.tobytes()))
    key = treedef, tuple(parts)
    try:
        hash(key)
    except TypeError:  # a static field that cannot be hashed
        return None
    return key


def memoised(size: int) -> Callable[[Callable], Callable]:
    """Decorator: ``fun`` (deterministic, its results never modified by callers) returns the result it already
    computed when called again with equal arguments (``value_key`` of its positional and keyword arguments),
    keeping the last ``size`` results."""

    def wrap(fun: Callable) -> Callable:
        memo: dict = {}

        @functools.wraps(fun)
        def wrapper(*args, **kwargs):
            key = value_key((args, kwargs))
            if key is None:
                return fun(*args, **kwargs)
            if key not in memo:
                if len(memo) >= size:
                    memo.pop(next(iter(memo)))  # the oldest
                memo[key] = fun(*args, **kwargs)
            return memo[key]

        return wrapper

    return wrap
