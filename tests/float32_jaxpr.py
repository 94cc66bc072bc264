"""The float64 equations of a jaxpr, found by walking it and every sub-jaxpr (scan, while, cond, pjit bodies):
how the float32 tests check that a float32 loop runs without a float64 operation anywhere."""

import jax
import jax.numpy as jnp


def _subjaxprs(value):
    for v in value if isinstance(value, (list, tuple)) else (value,):
        inner = getattr(v, "jaxpr", v)  # a ClosedJaxpr holds its Jaxpr in .jaxpr
        if hasattr(inner, "eqns"):
            yield inner


def float64_equations(jaxpr, where: str = "") -> list[str]:
    """'path/primitive' of every equation of ``jaxpr`` (recursively) with a float64 output."""
    found = []
    for eqn in jaxpr.eqns:
        path = f"{where}/{eqn.primitive}"
        if any(getattr(getattr(v, "aval", None), "dtype", None) == jnp.float64 for v in eqn.outvars):
            found.append(path)
        for value in eqn.params.values():
            for sub in _subjaxprs(value):
                found += float64_equations(sub, path)
    return found


def float64_equations_of(fn, *args) -> list[str]:
    return float64_equations(jax.make_jaxpr(fn)(*args).jaxpr)
