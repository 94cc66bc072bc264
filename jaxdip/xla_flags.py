"""XLA's own options (the ``XLA_FLAGS`` environment variable), which XLA reads once, when JAX starts its backend
(the first computation): whatever sets them must come before that."""

from __future__ import annotations

import os


def pending(options: dict[str, object]) -> list[str]:
    """``--name=value`` for each option not in ``XLA_FLAGS`` yet: one already there, the user's own setting or a
    parent process's, stays as it is."""
    have = os.environ.get("XLA_FLAGS", "")
    return [f"--{k}={str(v).lower()}" for k, v in options.items() if f"--{k}=" not in have]


def append(flags: list[str]) -> None:
    """Add ``flags`` (from ``pending``) to ``XLA_FLAGS``."""
    if flags:
        os.environ["XLA_FLAGS"] = " ".join([os.environ.get("XLA_FLAGS", ""), *flags]).strip()
