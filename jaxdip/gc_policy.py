"""Python's cyclic garbage collector, set for a ``jaxdip`` command's process.

Tracing and lowering a JAX program allocate a great many small containers, so with Python's default thresholds
(a young collection every 700 allocations, a full one every hundred young ones) a cold ``jaxdip run`` spends
0.6-0.9 s in the collector, most of it in a few full collections that walk every object the process holds,
modules and JAX's own caches included, none of which is garbage. A command's process therefore collects its
young objects every 50 000 allocations and stops scanning what it has loaded (``gc.freeze``): one cold
``--quick`` run then collects about ten times, in about 0.1 s. Measured on four cold experiments on this
project's 2-core CPU, 44-45 s of wall time against 49 s (docs/performance.md).

Cycles of garbage are still collected: the young generation about every 50 000 allocations, a full collection
after about ten million (Python's own rule also waits until a quarter of the long-lived objects are new). The
settings change when memory is given back, never a computed number.

Only the command's own process (``jaxdip.cli.entry``, a reproduction's workers): a script or a test that calls
``jaxdip.cli.main`` keeps its own collector as it set it.
"""

from __future__ import annotations

import gc

__all__ = ["for_a_command"]

YOUNG = 50_000  # allocations between young collections (Python's default: 700)
MIDDLE = 20  # young collections between collections of the middle generation (default 10)
OLD = 10  # middle collections between full ones (default 10)


def for_a_command() -> None:
    """Collect less often, and leave everything loaded so far out of every later collection."""
    gc.set_threshold(YOUNG, MIDDLE, OLD)
    gc.freeze()
