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
    """Periods of ``dt`` in ``duration``; OverflowError when that count is not a finite number (a config's
    ``loads()`` turns it into an error naming the value, see ``config.from_dict``)."""
    return int(round(duration / dt))


def _meminfo_available() -> int | None:
    """MemAvailable of /proc/meminfo (Linux), else total physical memory; None when neither is known."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def _status_bytes(field: str) -> int | None:
    """A size line of /proc/self/status (``VmSize``, ``VmData``) in bytes."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _rlimit_headroom() -> list[int]:
    """What this process may still map under ``ulimit -v`` (RLIMIT_AS) and ``ulimit -d`` (RLIMIT_DATA): the
    limit less what it uses now. A process that allocates past either gets an allocation failure, which XLA
    turns into an abort, whatever the machine has free."""
    try:
        import resource
    except ImportError:  # not a Unix
        return []
    out = []
    for limit, used in ((getattr(resource, "RLIMIT_AS", None), "VmSize"),
                        (getattr(resource, "RLIMIT_DATA", None), "VmData")):
        if limit is None:
            continue
        try:
            soft, _ = resource.getrlimit(limit)
        except (OSError, ValueError):
            continue
        if soft != resource.RLIM_INFINITY:
            out.append(max(0, soft - (_status_bytes(used) or 0)))
    return out


def _read_int(path: str) -> int | None:
    try:
        with open(path) as fh:
            text = fh.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None  # "max": no limit


def _cgroup_headroom() -> list[int]:
    """The memory limit of this process's control group (containers, systemd slices) less its usage: v2's
    memory.max and memory.current, else v1's limit_in_bytes and usage_in_bytes."""
    base = "/sys/fs/cgroup"
    try:
        with open("/proc/self/cgroup") as fh:
            lines = fh.read().splitlines()
    except OSError:
        lines = []
    out = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        if parts[0] == "0" and parts[1] == "":  # v2: one unified hierarchy
            root, names = base, ("memory.max", "memory.current")
        elif "memory" in parts[1].split(","):
            root, names = os.path.join(base, "memory"), ("memory.limit_in_bytes", "memory.usage_in_bytes")
        else:
            continue
        # inside a container the group's own folder is usually mounted as the root of the hierarchy
        for folder in (os.path.join(root, parts[2].lstrip("/")), root):
            limit = _read_int(os.path.join(folder, names[0]))
            if limit is not None:
                if limit < 1 << 60:  # v1 writes "no limit" as a huge number
                    out.append(max(0, limit - (_read_int(os.path.join(folder, names[1])) or 0)))
                break
    return out


def available_bytes() -> int:
    """Memory a new allocation of this process can still get: the least of what the machine has free
    (MemAvailable), what this process's RLIMIT_AS / RLIMIT_DATA leave it, and what its control group's memory
    limit leaves."""
    known = [b for b in (_meminfo_available(), *_rlimit_headroom(), *_cgroup_headroom()) if b is not None]
    return min(known) if known else 1 << 34


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
            raise ConfigError(name(k), f"{ld.what} would run {float(ld.steps):.3g} periods; at most {MAX_STEPS} fit "
                                       "a run")
        if ld.bytes > USABLE * avail:
            scale = ", ".join(_advice(k, name(k)) for k in ld.keys)
            raise ConfigError(
                name(ld.keys[0]),
                f"{ld.what} ({ld.trajectories} trajectories x {ld.steps} periods) would need about "
                f"{human(ld.bytes)} of memory and {human(avail)} are free: {scale}")
