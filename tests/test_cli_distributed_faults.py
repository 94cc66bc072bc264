"""``--distributed``'s faults: a coordinator that never answers, a port in use, and Ctrl-C while a process waits
for the others, including a Ctrl-C whose KeyboardInterrupt Python drops; each ends with exit status and one line,
and the folders as they were (``snapshots.snapshot``)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import pytest

from cli_faults_support import RUN, child_env, make_world, one_line, run_child
from snapshots import snapshot


@pytest.fixture
def world(tmp_path, monkeypatch):
    return make_world(tmp_path, monkeypatch)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _distributed(port, pid, *extra):
    return [*RUN, "--distributed", "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
            "--process-id", str(pid), *extra]


def _cpu_ticks(pid: int) -> int:
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])  # utime + stime


def _wait_until_idle(p: subprocess.Popen, limit_s: float = 120.0) -> None:
    """Until the child uses no CPU for half a second: its imports are done and it waits. A fixed sleep is not
    enough on a loaded machine, where the imports can take longer than the sleep, and a Ctrl-C that lands inside
    them is Python's to handle, not the command's."""
    time.sleep(1.0)
    end = time.monotonic() + limit_s
    last = _cpu_ticks(p.pid)
    while time.monotonic() < end and p.poll() is None:
        time.sleep(0.5)
        now = _cpu_ticks(p.pid)
        if now - last <= 1:
            return
        last = now


@pytest.mark.parametrize("pid", [1, 0])
def test_ctrl_c_during_the_connection(world, pid):
    """Process 1 waiting for a coordinator that never comes, process 0 for a process that never joins: Ctrl-C
    ends either at once, with one line (it used to be ignored until JAX aborted minutes later)."""
    work, victim = world
    before = snapshot(work), snapshot(victim)
    p = subprocess.Popen([sys.executable, "-m", "jaxdip.cli", *_distributed(_closed_port(), pid)], cwd=work,
                         env=child_env(), stderr=subprocess.PIPE, text=True)
    _wait_until_idle(p)
    assert p.poll() is None
    p.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    err = p.communicate(timeout=20)[1]
    assert p.returncode == 130 and one_line(err) == "interrupted: nothing was written", err
    assert time.monotonic() - t0 < 10
    assert (snapshot(work), snapshot(victim)) == before


def test_connection_timeout(world):
    work, victim = world
    before = snapshot(work), snapshot(victim)
    t0 = time.monotonic()
    r = run_child(_distributed(_closed_port(), 1, "--connect-timeout", "1"), work, timeout=60)
    line = one_line(r.stderr)
    assert r.returncode == 2 and line.startswith("error: --distributed: no coordinator answered at 127.0.0.1:"), line
    assert time.monotonic() - t0 < 30
    assert (snapshot(work), snapshot(victim)) == before


def test_coordinator_port_in_use(world):
    work, victim = world
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        before = snapshot(work), snapshot(victim)
        r = run_child(_distributed(busy.getsockname()[1], 0, "--connect-timeout", "5"), work, timeout=60)
    line = one_line(r.stderr)
    assert r.returncode == 2 and "is in use on this machine" in line, line
    assert (snapshot(work), snapshot(victim)) == before


def test_a_ctrl_c_swallowed_in_a_gc_callback_still_ends_the_connection_wait():
    """Python prints and drops an exception raised inside a garbage-collector callback (JAX runs one at every
    collection), so a Ctrl-C whose KeyboardInterrupt lands there is lost. The CLI's handler remembers it, and the
    distributed waits poll that record."""
    import gc
    import threading

    from jaxdip import distributed
    from jaxdip.cli_errors import interrupt_seen, remember_sigint

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers run in the main thread only")
    fired, lost = [], []

    def callback(phase, info):
        if phase == "start" and not fired:
            fired.append(True)
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(10_000):  # the handler runs between these bytecodes, inside the callback
                pass

    old_hook, sys.unraisablehook = sys.unraisablehook, lambda u: lost.append(u.exc_type)
    old = remember_sigint()
    assert not interrupt_seen()
    gc.callbacks.append(callback)
    try:
        gc.collect()
    finally:
        gc.callbacks.remove(callback)
        signal.signal(signal.SIGINT, old)
        sys.unraisablehook = old_hook
    assert lost == [KeyboardInterrupt]  # swallowed: without the record this Ctrl-C would be gone
    assert interrupt_seen()
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        distributed.wait_for_coordinator(f"127.0.0.1:{_closed_port()}", time.monotonic() + 30, interrupt_seen)
    with pytest.raises(KeyboardInterrupt):
        distributed._in_thread(lambda: time.sleep(5), time.monotonic() + 30, "never", interrupt_seen)
    assert time.monotonic() - t0 < 2
