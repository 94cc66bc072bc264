"""Resource estimates checked before anything compiles.

A config lists its big allocations as ``Load``s (``cfg.loads()``): how many trajectories are held in memory
at once, how many periods each runs, and how many floats each keeps. ``check`` turns a load that cannot fit in
the memory this machine has free, or a run longer than a step counter can count, into a one-line
``ConfigError`` naming the key to change, instead of an allocation failure (or the kernel's OOM killer)
minutes into a compile.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from jaxdip.config import ConfigError

FLOAT_BYTES = 8
# scan outputs are stacked, chunks concatenated and copied to the host: count each saved float three times
COPIES = 3
MAX_STEPS = 2**31 - 1  # step counters are int32 inside the loops
USABLE = 0.8  # leave room for XLA's own buffers and the rest of the machine


@dataclass(frozen=True)
class Load:
    what: str  # which part of the run, for the message
    keys: tuple[str, ...]  # config keys that scale it, the most direct first
    trajectories: int  # held in memory at once
    steps: int  # periods each simulates
    saved: int = 0  # floats each keeps (records for figures, histories)
    state: int = 256  # floats each carries (state, estimator memory, statistics)

    @property
    def bytes(self) -> int:
        return self.trajectories * (self.saved + self.state) * FLOAT_BYTES * COPIES


def steps_of(duration: float, dt: float) -> int:
    return int(round(duration / dt))


def available_bytes() -> int:
    """Memory free for a new process (MemAvailable on Linux; total physical memory elsewhere)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 1 << 34


def human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} EiB"


def _advice(key: str, shown: str) -> str:
    if key == "record_every":
        return f"save less (raise {shown})"
    if key in ("duration", "T", "steps") or key.endswith(("_duration", "_steps")):
        return f"shorten {shown}"
    return f"lower {shown}"


def check(loads: list[Load], available: int | None = None, flag_keys: dict[str, str] | None = None) -> None:
    """Raise ConfigError for the first load that cannot run here; ``flag_keys`` maps a key to the flag that set it."""
    flag_keys = flag_keys or {}
    avail = available_bytes() if available is None else available
    name = lambda k: flag_keys.get(k, k)
    for ld in loads:
        if ld.steps > MAX_STEPS:
            k = next((k for k in ld.keys if k != "seeds"), ld.keys[0])
            raise ConfigError(name(k), f"{ld.what} would run {ld.steps:.3g} periods; at most {MAX_STEPS} fit a run")
        if ld.bytes > USABLE * avail:
            scale = ", ".join(_advice(k, name(k)) for k in ld.keys)
            raise ConfigError(
                name(ld.keys[0]),
                f"{ld.what} ({ld.trajectories} trajectories x {ld.steps} periods) would need about "
                f"{human(ld.bytes)} of memory and {human(avail)} are free: {scale}")
