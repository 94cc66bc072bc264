"""Several processes, one run: ``jax.distributed`` set-up for ``--distributed`` and the few helpers around it.

With ``jax.distributed`` initialised, ``jax.devices()`` lists the devices of every process and ``monte_carlo``
shards its seeds over all of them (see docs/engine.md). Every process runs the same program; process 0 is the
one that writes (result folders, checkpoints) and draws progress bars.

Where the values come from, first found wins, separately for each of the three:
``--coordinator`` / ``--num-processes`` / ``--process-id``, then ``JAXDIP_COORDINATOR`` /
``JAXDIP_NUM_PROCESSES`` / ``JAXDIP_PROCESS_ID``, then JAX's own detection of the cluster (SLURM, Open MPI, ...;
``JAX_COORDINATOR_ADDRESS`` also counts).
"""

from __future__ import annotations

import os
import re
from typing import Any, Optional

ENV = {"coordinator": "JAXDIP_COORDINATOR", "num_processes": "JAXDIP_NUM_PROCESSES",
       "process_id": "JAXDIP_PROCESS_ID"}
FLAG = {"coordinator": "--coordinator", "num_processes": "--num-processes", "process_id": "--process-id"}


class DistributedError(ValueError):
    """A value for ``--distributed`` that is missing or invalid, or a coordinator that cannot be reached."""


def _int(value: str, where: str) -> int:
    try:
        return int(str(value).strip())
    except ValueError:
        raise DistributedError(f"{where}: expected an integer, got {value!r}") from None


def resolve(coordinator: Optional[str] = None, num_processes: Optional[int | str] = None,
            process_id: Optional[int | str] = None, environ: Optional[dict] = None) -> dict[str, Any]:
    """The (coordinator, num_processes, process_id) to initialise with, each from its flag or its JAXDIP_
    variable, validated; ``None`` where neither gives it (JAX's cluster detection then fills it in)."""
    env = os.environ if environ is None else environ
    got = {"coordinator": coordinator, "num_processes": num_processes, "process_id": process_id}
    where = {}
    for name, value in got.items():
        where[name] = FLAG[name]
        if value is None and env.get(ENV[name], "").strip():
            got[name], where[name] = env[ENV[name]].strip(), ENV[name]
    c = got["coordinator"]
    if c is not None:
        m = re.fullmatch(r"(\[[0-9A-Fa-f:.]+\]|[^\s:\[\]]+):(\d+)", str(c).strip())
        if not m or not 0 < int(m.group(2)) < 65536:
            raise DistributedError(f"{where['coordinator']}: expected HOST:PORT (port 1-65535), got {c!r}")
        got["coordinator"] = str(c).strip()
    for name in ("num_processes", "process_id"):
        if got[name] is not None:
            got[name] = _int(got[name], where[name])
    n, i = got["num_processes"], got["process_id"]
    if n is not None and n < 1:
        raise DistributedError(f"{where['num_processes']}: must be >= 1, got {n}")
    if i is not None and i < 0:
        raise DistributedError(f"{where['process_id']}: must be >= 0, got {i}")
    if n is not None and i is not None and i >= n:
        raise DistributedError(f"{where['process_id']}: must be below the number of processes ({n}), got {i}")
    return got


def initialize(coordinator: Optional[str] = None, num_processes: Optional[int | str] = None,
               process_id: Optional[int | str] = None, timeout_s: int = 300) -> tuple[int, int]:
    """Initialise ``jax.distributed`` (before any JAX computation); returns (process_id, num_processes).

    On CPU the cross-process collectives are gloo's. Raises ``DistributedError`` with a one-line reason.
    """
    import jax

    got = resolve(coordinator, num_processes, process_id)
    # CPU collectives: without an implementation a CPU computation spanning processes cannot run. gloo is the
    # default of recent JAX; naming it keeps versions whose default is "none" working.
    try:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    except (AttributeError, KeyError, ValueError):
        pass
    try:
        jax.distributed.initialize(got["coordinator"], got["num_processes"], got["process_id"],
                                   initialization_timeout=timeout_s)
    except ValueError as e:
        missing = [FLAG[k] for k, v in got.items() if v is None]
        if missing:
            raise DistributedError(
                f"no cluster detected (SLURM, Open MPI, ...) and no value for {', '.join(missing)} "
                f"(or {', '.join(ENV[k] for k, v in got.items() if v is None)})") from None
        raise DistributedError(str(e)) from None
    except Exception as e:  # noqa: BLE001  (XLA's runtime errors): one line, not a traceback
        # the backend already started, or the coordinator could not be reached within the timeout
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise DistributedError(f"cannot join the coordinator at {got['coordinator'] or '(detected)'}: {first}") \
            from None
    return jax.process_index(), jax.process_count()


def is_main() -> bool:
    """Whether this is process 0 (always, without ``jax.distributed``): the one that writes and reports."""
    import jax

    return jax.process_index() == 0


def agree(ok: bool) -> bool:
    """Process 0's ``ok``, on every process (a collective: every process must call it, in the same order).
    Without ``jax.distributed`` it is ``ok`` itself, and nothing runs."""
    import jax

    if jax.process_count() == 1:
        return ok
    import numpy as np
    from jax.experimental import multihost_utils

    return bool(multihost_utils.broadcast_one_to_all(np.int32(bool(ok))))
