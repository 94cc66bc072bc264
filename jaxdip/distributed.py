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

import errno
import os
import re
import socket
import sys
import tempfile
import threading
import time
from typing import Any, Callable, Optional

from jaxdip.messages import shown

ENV = {"coordinator": "JAXDIP_COORDINATOR", "num_processes": "JAXDIP_NUM_PROCESSES",
       "process_id": "JAXDIP_PROCESS_ID"}
FLAG = {"coordinator": "--coordinator", "num_processes": "--num-processes", "process_id": "--process-id"}


MAX_PROCESSES = 1 << 20  # JAX counts processes in 32 bits; a million is beyond any cluster this would meet


class DistributedError(ValueError):
    """A value for ``--distributed`` that is missing or invalid, or a coordinator that cannot be reached.
    ``stuck``: a call into JAX's runtime is still waiting and cannot be cancelled; end the process."""

    def __init__(self, message: str, stuck: bool = False):
        super().__init__(message)
        self.stuck = stuck


def _int(value: str, where: str) -> int:
    try:
        return int(str(value).strip())
    except ValueError:
        raise DistributedError(f"{where}: expected an integer, got {shown(value)}") from None


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
            raise DistributedError(f"{where['coordinator']}: expected HOST:PORT (port 1-65535), got {shown(c)}")
        got["coordinator"] = str(c).strip()
    for name in ("num_processes", "process_id"):
        if got[name] is not None:
            got[name] = _int(got[name], where[name])
    n, i = got["num_processes"], got["process_id"]
    if n is not None and not 1 <= n <= MAX_PROCESSES:
        raise DistributedError(f"{where['num_processes']}: must be between 1 and {MAX_PROCESSES}, got {shown(n, 24)}")
    if i is not None and i < 0:
        raise DistributedError(f"{where['process_id']}: must be >= 0, got {i}")
    if n is not None and i is not None and i >= n:
        raise DistributedError(f"{where['process_id']}: must be below the number of processes ({n}), got {i}")
    return got


DEFAULT_TIMEOUT_S = 60.0  # --connect-timeout: long enough for a cluster's processes to start, short enough to notice
MAX_TIMEOUT_S = 86400.0


def _host_port(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    return host.strip("[]"), int(port)


def wait_for_coordinator(address: str, deadline: float, stop: Optional[Callable[[], bool]] = None) -> None:
    """Until ``deadline`` (``time.monotonic``), try a plain TCP connection to ``address`` every quarter second:
    a coordinator that is not up yet may still come, one that never answers is reported here, in Python, where
    Ctrl-C works, instead of inside ``jax.distributed.initialize`` (which ignores SIGINT and aborts the process
    with a C++ stack trace when its own timeout passes). ``stop()`` true (a Ctrl-C seen, even one swallowed on
    its way: a KeyboardInterrupt raised inside a garbage-collector callback, such as JAX's, is printed and
    dropped) ends the wait as Ctrl-C does."""
    host, port = _host_port(address)
    last = "no answer"
    while True:
        _check_stop(stop)
        left = deadline - time.monotonic()
        if left <= 0:
            raise DistributedError(f"no coordinator answered at {address} ({last}); start process 0 first, check "
                                   "the address, or raise --connect-timeout")
        try:
            with socket.create_connection((host, port), timeout=min(1.0, left)):
                return
        except socket.gaierror as e:
            raise DistributedError(f"cannot resolve the coordinator's host {shown(host)}: {e.strerror or e}") from None
        except OSError as e:
            last = e.strerror or type(e).__name__
        time.sleep(min(0.25, max(0.0, deadline - time.monotonic())))


def check_port_free(address: str) -> None:
    """Process 0 serves the coordinator on the address's port: one already taken is refused now, in one line."""
    _, port = _host_port(address)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("", port))
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                raise DistributedError(f"port {port} of the coordinator is in use on this machine; choose another "
                                       "--coordinator port") from None
            raise DistributedError(f"cannot serve the coordinator on port {port}: {e.strerror or e}") from None


class _StderrHeld:
    """File descriptor 2 redirected to a temporary file (XLA's C++ runtime logs there directly): shown again on
    success, dropped when the connection fails, so a failure stays one line."""

    def __enter__(self):
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        return self

    def __exit__(self, exc_type, *exc) -> bool:
        sys.stderr.flush()
        os.dup2(self._saved, 2)
        os.close(self._saved)
        if exc_type is None:
            self._file.seek(0)
            text = self._file.read()
            if text:
                sys.stderr.write(text.decode("utf-8", "replace"))
                sys.stderr.flush()
        self._file.close()
        return False


def _check_stop(stop: Optional[Callable[[], bool]]) -> None:
    if stop is not None and stop():
        raise KeyboardInterrupt


def _in_thread(fn, deadline: float, what: str, stop: Optional[Callable[[], bool]] = None):
    """``fn()`` in a helper thread while this one waits, so Ctrl-C (a KeyboardInterrupt here) and ``deadline``
    both end the wait; a call still running then is stuck in C++ (``DistributedError.stuck``), and the caller
    must end the process without waiting for it."""
    box: dict = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as e:  # noqa: BLE001  (handed to the waiting thread)
            box["error"] = e

    t = threading.Thread(target=target, name="jax.distributed.initialize", daemon=True)
    t.start()
    while t.is_alive():
        _check_stop(stop)
        if time.monotonic() >= deadline:
            raise DistributedError(f"{what}; raise --connect-timeout if the other processes start later",
                                   stuck=True)
        t.join(0.1)
    if "error" in box:
        raise box["error"]
    return box.get("value")


def initialize(coordinator: Optional[str] = None, num_processes: Optional[int | str] = None,
               process_id: Optional[int | str] = None, timeout_s: float = DEFAULT_TIMEOUT_S,
               stop: Optional[Callable[[], bool]] = None) -> tuple[int, int]:
    """Initialise ``jax.distributed`` (before any JAX computation); returns (process_id, num_processes).

    Every process waits at most ``timeout_s`` for the others, and Ctrl-C ends the wait. On CPU the
    cross-process collectives are gloo's. Raises ``DistributedError`` with a one-line reason. ``stop``: a
    predicate polled while waiting (the CLI's record of a Ctrl-C); true ends the wait with KeyboardInterrupt.
    """
    import jax

    deadline = time.monotonic() + timeout_s
    got = resolve(coordinator, num_processes, process_id)
    if got["coordinator"] is not None and got["process_id"] is not None:
        if got["process_id"] == 0:
            check_port_free(got["coordinator"])
        else:
            wait_for_coordinator(got["coordinator"], deadline, stop)
    # CPU collectives: without an implementation a CPU computation spanning processes cannot run. gloo is the
    # default of recent JAX; naming it keeps versions whose default is "none" working.
    try:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    except (AttributeError, KeyError, ValueError):
        pass
    # JAX's own timeout is left longer than ours: when it passes, it aborts the process
    left = max(1.0, deadline - time.monotonic())
    where = got["coordinator"] or "(detected)"
    try:
        with _StderrHeld():
            _in_thread(lambda: jax.distributed.initialize(got["coordinator"], got["num_processes"],
                                                          got["process_id"],
                                                          initialization_timeout=int(left) + 30),
                       deadline, f"the processes did not all join at {where} within {timeout_s:g} s", stop)
    except DistributedError:
        raise
    except ValueError as e:
        missing = [FLAG[k] for k, v in got.items() if v is None]
        if missing:
            raise DistributedError(
                f"no cluster detected (SLURM, Open MPI, ...) and no value for {', '.join(missing)} "
                f"(or {', '.join(ENV[k] for k, v in got.items() if v is None)})") from None
        raise DistributedError(str(e)) from None
    except Exception as e:  # noqa: BLE001  (XLA's runtime errors): one line, not a traceback
        # the backend already started, or the coordinator could not be reached
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise DistributedError(f"cannot join the coordinator at {where}: {first}") from None
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
