"""XLA's own options (the ``XLA_FLAGS`` environment variable), which XLA reads once, when JAX starts its backend
(the first computation): whatever sets them must come before that. Among them the compile effort, how hard XLA
works on every program a process compiles.

On CPU most of a short run's wall time is XLA compiling its loops, not running them. XLA's default (``"full"``)
optimises each fused kernel with LLVM at -O3 through its newer fusion emitters: the fastest code at the highest
compile cost. ``"balanced"`` (LLVM -O1, the older elemental emitters) compiles in about 40 % less time and its
code runs about as fast on this project's loops; ``"fast"`` (-O0) about halves compile time and its code runs
1.2-4x slower. Results agree across levels to the last bits only (reassociated, differently vectorised sums),
which is why the level is one per process, set before JAX starts and recorded with a run's results, never
chosen per program: seed i gives the same bits alone, in a batch and sharded only within one level.
"""

from __future__ import annotations

import os

EFFORTS: dict[str, dict[str, object]] = {
    "full": {},
    "balanced": {"xla_backend_optimization_level": 1, "xla_cpu_use_fusion_emitters": False},
    "fast": {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False},
}
_OPTIONS = ("xla_backend_optimization_level", "xla_cpu_use_fusion_emitters")


def pending(options: dict[str, object]) -> list[str]:
    """``--name=value`` for each option not in ``XLA_FLAGS`` yet: one already there, the user's own setting or a
    parent process's, stays as it is."""
    have = os.environ.get("XLA_FLAGS", "")
    return [f"--{k}={_text(v)}" for k, v in options.items() if f"--{k}=" not in have]


def append(flags: list[str]) -> None:
    """Add ``flags`` (from ``pending``) to ``XLA_FLAGS``."""
    if flags:
        os.environ["XLA_FLAGS"] = " ".join([os.environ.get("XLA_FLAGS", ""), *flags]).strip()


def set_effort(level: str) -> None:
    """Make ``level`` the compile effort of every program this process (and the processes it starts) compiles,
    the library's, a user's ``jax.jit`` and the small programs behind eager operations alike. Options already in
    ``XLA_FLAGS`` stay: ``effort()`` then tells the level in force. Call it before JAX's first computation."""
    if level not in EFFORTS:
        raise ValueError(f"compile effort must be one of {', '.join(EFFORTS)}, got {level!r}")
    append(pending(EFFORTS[level]))


def effort() -> str:
    """The compile effort ``XLA_FLAGS`` gives this process: ``"full"`` where it sets none of the levels' options.
    A ValueError names a setting of those options that is none of the levels."""
    have = dict(f[2:].split("=", 1) for f in os.environ.get("XLA_FLAGS", "").split()
                if f.startswith("--") and "=" in f and f[2:].split("=", 1)[0] in _OPTIONS)
    for level, options in EFFORTS.items():
        if have == {k: _text(v) for k, v in options.items()}:
            return level
    raise ValueError(f"XLA_FLAGS sets {', '.join(f'{k}={v}' for k, v in have.items())}: none of the compile "
                     f"efforts ({', '.join(EFFORTS)})")


def _text(value: object) -> str:
    return str(value).lower()


def cache_folder() -> str:
    """Where the on-disk caches go: ``$JAXDIP_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxdip/xla``."""
    return os.environ.get("JAXDIP_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "jaxdip", "xla")


def use_compile_cache() -> str | None:
    """Keep XLA's compiled code on disk so a second run of the same loops skips compilation.

    The folder is ``$JAXDIP_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxdip/xla`` (``~/.cache/jaxdip/xla``). JAX keys
    each entry by the computation, the jaxlib version and the XLA flags (so the host device count), so a stale
    entry is never used; it only saves time. ``--no-compile-cache`` turns it off for one run. Returns None, or why
    the cache is off (a folder it cannot create).
    """
    folder = cache_folder()
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as e:
        return f"compilation cache off: cannot create {folder}: {e.strerror or e}"
    import jax

    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)  # a threshold would make the cache depend on load
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    # The key hashes the lowered module with its source locations, by default the whole Python call stack of
    # each operation: `jaxdip run`, a `reproduce` worker and a script calling the same experiment then never
    # share an entry, and an edit that shifts a line of the CLI or the runner misses every cached program. The
    # innermost frame alone (the line that made the operation) keeps the key to the code that shapes the program;
    # locations are debug information, so the compiled code is the same (docs/performance.md, warm start).
    jax.config.update("jax_include_full_tracebacks_in_locations", False)
    # and the traced programs before it, so a warm run skips tracing and lowering as well (jaxdip.program_cache)
    from jaxdip import program_cache

    program_cache.enable(os.path.join(folder, "programs"))
    return None
