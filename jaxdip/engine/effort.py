"""How hard XLA works on the programs the library compiles: the compile effort.

On CPU most of a short run's wall time is XLA compiling its loops, not running them: a ``--quick`` reproduction
ran its compiled code for under a tenth of its time. XLA's default (``"full"``) optimises each fused kernel with
LLVM at -O3 through its newer fusion emitters; that buys the fastest code at the highest compile cost. Two
cheaper levels, measured on this project's loops (2-core CPU, cold compilation cache):

- ``"fast"``: LLVM at -O0 and XLA's older elemental emitters. Compile time about halves (a quick reproduction's
  summed experiment time 320 -> 175 s); compiled code runs 1.2-4x slower, so it suits programs that run
  briefly, as in most quick runs.
- ``"balanced"``: LLVM at -O1, older emitters. Compile time about -40 %; code about as fast as ``"full"`` on
  these loops (the quick reproduction's run-dominated experiment, ifn-protection, kept its speed).

Results agree across levels to the last bits only (relative differences up to ~1e-8 on quantities that are
means of near-zero numbers; reassociated and differently vectorised sums). A run's seed guarantees (seed i the
same alone, in a batch, sharded) hold within one level, which is why the level is set per run, never chosen
per program from its size.

``jit`` and ``filter_jit`` below compile one variant per level, chosen when the function is called from the
level in force (``effort(level)``, else ``set_default``'s; ``"full"`` unless changed). A call under a trace of
an enclosing function (its arguments are tracers) compiles nothing itself, and other backends than CPU always
get ``"full"``.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
from typing import Any, Callable, Iterator

import equinox as eqx
import jax

from jaxdip import xla_flags

LEVELS: dict[str, dict[str, Any]] = {
    "full": {},
    "balanced": {"xla_backend_optimization_level": 1, "xla_cpu_use_fusion_emitters": False},
    "fast": {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False},
}

_default = "full"
_level: contextvars.ContextVar[str | None] = contextvars.ContextVar("jaxdip_compile_effort", default=None)


def _check(level: str) -> str:
    if level not in LEVELS:
        raise ValueError(f"compile effort must be one of {', '.join(LEVELS)}, got {level!r}")
    return level


def current() -> str:
    """The compile effort in force."""
    level = _level.get()
    return _default if level is None else level


def set_default(level: str) -> None:
    """The compile effort outside any ``effort(...)`` block (``"full"`` unless set)."""
    global _default
    _default = _check(level)


@contextlib.contextmanager
def effort(level: str | None) -> Iterator[None]:
    """Compile what is first called inside this block at ``level`` (``None``: leave the level as it is)."""
    if level is None:
        yield
        return
    token = _level.set(_check(level))
    try:
        yield
    finally:
        _level.reset(token)


def _options() -> dict[str, Any] | None:
    opts = LEVELS[current()]
    if not opts or jax.default_backend() != "cpu":
        return None
    return opts


def set_process_level(level: str) -> None:
    """Make ``level`` XLA's default for every program this process compiles, the library's own, a user's ``jax.jit``
    and the small programs behind eager operations alike, by adding its options to ``XLA_FLAGS``.

    XLA reads the flags when JAX starts its backend, so this must come before the first computation (else a
    RuntimeError). ``effort(...)`` still picks explicit levels for the library's programs; ``"full"`` then
    means this default. The test suite uses it (most of its time is compiling programs that run for
    milliseconds).
    """
    flags = xla_flags.pending(LEVELS[_check(level)])
    if not flags:
        return
    from jax._src import xla_bridge

    if getattr(xla_bridge, "backends_are_initialized", lambda: False)():
        raise RuntimeError("set_process_level must come before JAX's first computation (its backend has started)")
    xla_flags.append(flags)


def traced(*trees) -> bool:
    """Whether any leaf of ``trees`` is a tracer (the call is part of an enclosing trace)."""
    return any(isinstance(leaf, jax.core.Tracer) for t in trees for leaf in jax.tree_util.tree_leaves(t))


class _PerLevel:
    """One compiled function per compile effort, the variant picked at each call."""

    def __init__(self, fun: Callable, make: Callable[[Callable, dict | None], Callable]):
        self._fun, self._make = fun, make
        self._variants: dict[tuple, Callable] = {}
        functools.update_wrapper(self, fun)

    def _variant(self, opts: dict | None) -> Callable:
        key = tuple(sorted(opts.items())) if opts else ()
        f = self._variants.get(key)
        if f is None:
            f = self._variants[key] = self._make(self._fun, opts)
        return f

    def __call__(self, *args, **kwargs):
        opts = None if traced(args, kwargs) else _options()
        if opts is None:
            return self._variant(None)(*args, **kwargs)
        try:
            return self._variant(opts)(*args, **kwargs)
        except ValueError as e:
            # inside an enclosing jit with no traced argument: JAX takes options from top-level programs only
            if "compiler_options" not in str(e):
                raise
            return self._variant(None)(*args, **kwargs)


def jit(fun: Callable | None = None, **jit_kwargs) -> Callable:
    """``jax.jit(fun, **jit_kwargs)`` compiled at the compile effort in force when it is called."""
    if fun is None:
        return functools.partial(jit, **jit_kwargs)
    return _PerLevel(fun, lambda f, o: jax.jit(f, compiler_options=o, **jit_kwargs))


def filter_jit(fun: Callable | None = None, **jit_kwargs) -> Callable:
    """``eqx.filter_jit(fun, **jit_kwargs)`` compiled at the compile effort in force when it is called."""
    if fun is None:
        return functools.partial(filter_jit, **jit_kwargs)
    return _PerLevel(fun, lambda f, o: eqx.filter_jit(f, compiler_options=o, **jit_kwargs))
