"""Faults of every class the command line promises to stop cleanly on: exit status, exactly one line on standard
error of at most 300 characters with no raw control character, and the working folder and a victim folder
beside it left exactly as they were (``snapshots.snapshot``).

The table runs in this process (nothing in it compiles); what needs a real process (a closed pipe, a FIFO, an
ASCII-only terminal, a memory limit, a deleted working folder, Ctrl-C during a connection) runs as a child.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import os
import signal
import socket
import subprocess
import sys
import time
import warnings

import pytest

from jaxdip import cli, reproduce_pool
import experiments.dip_lqr as dip_lqr
from jaxdip.resources import FLOAT_BYTES, COPIES, USABLE, available_bytes
from snapshots import snapshot

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LONG = "x" * 100_000
ESC = "\x1b]0;owned\x07\x1b[2J"  # a terminal title change and a screen clear


def one_line(err: str) -> str:
    """The single line of ``err``, after checking the contract's form."""
    assert err.endswith("\n") and err.count("\n") == 1, repr(err[:2000])
    line = err[:-1]
    assert len(line) <= 300, len(line)
    assert not any(ord(c) < 32 or 0x7F <= ord(c) < 0xA0 for c in line), repr(line)
    return line


@pytest.fixture
def world(tmp_path, monkeypatch):
    """``work`` (the working folder, with a user's file and folder) and ``victim`` beside it."""
    work, victim = tmp_path / "work", tmp_path / "victim"
    for d in (work, victim):
        (d / "sub").mkdir(parents=True)
        (d / "notes.txt").write_text("mine\n")
        (d / "sub" / "data.csv").write_text("1,2\n")
    (work / "bad_seeds.toml").write_text("seeds = -3\n")
    (work / "bad_dt.toml").write_text('dt = "fast"\n')
    os.mkfifo(work / "fifo.toml")
    monkeypatch.chdir(work)
    monkeypatch.setenv("JAXDIP_NO_PROGRESS", "1")
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # restored after the test
    return work, victim


def _sock(path):
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(path))
    return s


RUN = ["run", "dip-lqr", "--quick", "--out", "o"]

CASES = [
    # -- a value in the config file is checked even when a flag replaces it
    ("file_value_under_seeds_flag", [*RUN, "--config", "bad_seeds.toml", "--seeds", "4"], "seeds"),
    ("file_value_under_set", [*RUN, "--config", "bad_seeds.toml", "--set", "seeds=4"], "seeds"),
    ("file_type_under_set", [*RUN, "--config", "bad_dt.toml", "--set", "dt=0.001"], "dt"),
    ("set_replaced_by_later_set", [*RUN, "--set", "seeds=-1", "--set", "seeds=4"], "seeds"),
    # -- numbers that overflow, or are not numbers
    ("subnormal_dt", [*RUN, "--set", "dt=5e-324"], "dt"),
    ("period_count_overflows", [*RUN, "--set", "dt=1e-300", "--set", "duration=1e10"], "dt"),
    ("duration_1e308", [*RUN, "--set", "duration=1e308"], "duration"),
    ("nan_weight", [*RUN, "--set", "R=nan"], "R"),
    ("weight_1e308_breaks_the_design", [*RUN, "--set", "Q=[1e308,1,1,0,0,0]"], "Q"),
    ("float_beyond_float", [*RUN, "--set", f"init_radius={10**400}"], "init_radius"),
    # -- special files as --config are refused without being read (a FIFO would block forever)
    ("config_fifo", [*RUN, "--config", "fifo.toml"], "--config"),
    ("config_device", [*RUN, "--config", "/dev/zero"], "--config"),
    ("config_socket", [*RUN, "--config", "sock"], "--config"),
    ("bench_out_device", ["bench", "--quick", "--out", "/dev/null"], "--out"),
    ("run_out_socket", ["run", "dip-lqr", "--quick", "--out", "sock"], "--out"),
    # -- user text shortened, control characters escaped
    ("long_set_value", [*RUN, "--set", f"seeds={LONG}"], "seeds"),
    ("long_set_key", [*RUN, "--set", f"{LONG}=1"], "x"),
    ("long_experiment_id", ["run", LONG, "--out", "o"], "x"),
    ("long_seeds_flag", [*RUN, "--seeds", "9" * 100_000], "--seeds"),
    ("escape_in_experiment_id", ["run", f"dip{ESC}", "--out", "o"], "dip"),
    ("escape_in_set_value", [*RUN, "--set", f"seeds=1{ESC}"], "seeds"),
    ("escape_in_config_path", [*RUN, "--config", f"x{ESC}.toml"], "--config"),
    ("escape_in_out_under_file", ["run", "dip-lqr", "--quick", "--out", f"notes.txt/{ESC}"], "--out"),
    ("path_too_long", ["run", "dip-lqr", "--quick", "--out", "d/" * 3000], "--out"),
    ("name_too_long", ["run", "dip-lqr", "--quick", "--out", "n" * 300], "--out"),
    # -- --jobs and --out of reproduce, and the distributed settings, before anything starts
    ("jobs_zero", ["reproduce", "--quick", "--jobs", "0", "--out", "r"], "--jobs"),
    ("jobs_negative", ["reproduce", "--quick", "--jobs", "-3", "--out", "r"], "--jobs"),
    ("jobs_absurd", ["reproduce", "--quick", "--jobs", str(10**9), "--out", "r"], "--jobs"),
    ("jobs_word", ["reproduce", "--quick", "--jobs", "many", "--out", "r"], "--jobs"),
    ("reproduce_out_is_file", ["reproduce", "--quick", "--jobs", "2", "--out", "notes.txt"], "--out"),
    ("reproduce_out_under_file", ["reproduce", "--quick", "--jobs", "2", "--out", "notes.txt/r"], "--out"),
    ("connect_timeout_without_distributed", [*RUN, "--connect-timeout", "5"], "--connect-timeout"),
    ("connect_timeout_zero", [*RUN, "--distributed", "--connect-timeout", "0"], "--connect-timeout"),
    ("connect_timeout_inf", [*RUN, "--distributed", "--connect-timeout", "inf"], "--connect-timeout"),
    ("coordinator_long", [*RUN, "--distributed", "--coordinator", LONG], "--distributed"),
    ("process_id_escape", [*RUN, "--distributed", "--process-id", ESC], "--distributed"),
]


def test_enough_cases():
    assert len(CASES) >= 20 and len({c[0] for c in CASES}) == len(CASES)


@pytest.mark.parametrize("name, argv, key", CASES, ids=[c[0] for c in CASES])
def test_fault(world, capsys, monkeypatch, name, argv, key):
    work, victim = world
    started = []
    monkeypatch.setattr(reproduce_pool.subprocess, "Popen", lambda *a, **k: started.append(a) or pytest.fail(str(a)))
    sock = _sock(work / "sock")
    try:
        before = snapshot(work), snapshot(victim)
        code = cli.main(list(argv))
        line = one_line(capsys.readouterr().err)
        assert code == 2
        assert line.startswith(f"error: {key}"), line
        assert (snapshot(work), snapshot(victim)) == before
        assert not started  # no worker process
    finally:
        sock.close()


# ---- faults during the work itself: a full disk, memory running out --------------------------------------


def _failing_run(exc):
    def run(cfg, ctx):
        raise exc

    return run


@pytest.mark.parametrize("exc, start", [
    (OSError(errno.ENOSPC, "No space left on device", "/x/metrics.json"), "error: --out: cannot write"),
    (OSError(errno.EDQUOT, "Disk quota exceeded", "/x/report.md"), "error: --out: cannot write"),
    (OSError(errno.EROFS, "Read-only file system", "/x/a.png"), "error: --out: cannot write"),
    (MemoryError(), "error: --seeds: the run ran out of memory"),
    (RuntimeError("RESOURCE_EXHAUSTED: Out of memory allocating 8589934592 bytes."),
     "error: --seeds: the run ran out of memory"),
])
def test_fault_during_the_run(world, capsys, monkeypatch, exc, start):
    """The run's folder is never committed and the staging folder is gone: both folders as they were."""
    work, victim = world
    monkeypatch.setattr(dip_lqr, "EXPERIMENT", dataclasses.replace(dip_lqr.EXPERIMENT, run=_failing_run(exc)))
    before = snapshot(work), snapshot(victim)
    code = cli.main(RUN)
    line = one_line(capsys.readouterr().err)
    assert code == 2 and line.startswith(start), line
    assert (snapshot(work), snapshot(victim)) == before


# ---- warnings before a refusal ------------------------------------------------------------------------------


def test_warnings_before_a_refusal_are_dropped(world, capsys, monkeypatch):
    """A Python warning, a log record (as JAX's) and jaxdip's own warning, all before the config is refused:
    still one line."""
    from jaxdip import config as C

    load = C.load

    def noisy(*a, **k):
        warnings.warn("something deprecated", DeprecationWarning, stacklevel=1)
        logging.getLogger("jax._src.xla_bridge").warning("An accelerator may be present but is not used")
        return load(*a, **k)

    monkeypatch.setattr(C, "load", noisy)
    monkeypatch.setenv("JAXDIP_CACHE_DIR", str(world[0] / "notes.txt" / "cache"))  # cannot be made: a warning
    before = snapshot(world[0]), snapshot(world[1])
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        code = cli.main([*RUN, "--set", "seeds=0"])
    line = one_line(capsys.readouterr().err)
    assert code == 2 and line.startswith("error: seeds: "), line
    assert (snapshot(world[0]), snapshot(world[1])) == before


def test_warnings_of_a_command_that_goes_on_are_shown(world, capsys, monkeypatch):
    from jaxdip import runner

    registry = runner.registry

    def noisy():
        logging.getLogger("jax").warning("held back, then shown")
        return registry()

    monkeypatch.setattr(runner, "registry", noisy)
    assert cli.main(["list"]) == 0
    out, err = capsys.readouterr()
    assert "dip-lqr" in out.split()
    assert err == "warning: held back, then shown\n"


# ---- faults that need a process of their own -----------------------------------------------------------------


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SLURM_", "OMPI_", "PMI_", "JAX_COORD"))}
    env.update(JAXDIP_NO_PROGRESS="1", **extra)
    return env


def _child(args, cwd, timeout=60, **popen):
    popen.setdefault("stdout", subprocess.PIPE)
    return subprocess.run([sys.executable, "-m", "jaxdip.cli", *args], cwd=cwd, env=popen.pop("env", _env()),
                          stderr=subprocess.PIPE, text=True, timeout=timeout, **popen)


def test_numpy_warning_before_a_late_refusal(world):
    """R = 1e308: NumPy warns of an overflow in the Riccati design, which then fails: one line, not the warning's
    two and the error's one."""
    work, victim = world
    before = snapshot(work), snapshot(victim)
    r = _child([*RUN, "--set", "R=1e308"], work)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: Q, R: cannot solve the CARE"), r.stderr
    assert (snapshot(work), snapshot(victim)) == before


def test_fifo_config_does_not_hang(world):
    work, victim = world
    before = snapshot(work), snapshot(victim)
    r = _child([*RUN, "--config", "fifo.toml"], work, timeout=30)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: --config: fifo.toml is a FIFO"), r.stderr
    assert (snapshot(work), snapshot(victim)) == before


@pytest.mark.parametrize("argv", [
    ["bench", "--quick", "--out", "fifo.toml"],
    ["reproduce", "--quick", "--only", "dip-lqr,eki-linear", "--out", "repro"],  # its REPORT.md is a FIFO
])
def test_fifo_as_output_does_not_hang(world, argv):
    work, victim = world
    (work / "repro").mkdir()
    os.mkfifo(work / "repro" / "REPORT.md")
    before = snapshot(work), snapshot(victim)
    r = _child(argv, work, timeout=30)
    assert r.returncode == 2 and "is a FIFO" in one_line(r.stderr), r.stderr
    assert (snapshot(work), snapshot(victim)) == before


def test_closed_pipe_exits_quietly(world):
    """``jaxdip config dip-lqr | head -0``: the reader is gone before the first write."""
    before = snapshot(world[0]), snapshot(world[1])
    p = subprocess.Popen([sys.executable, "-m", "jaxdip.cli", "config", "dip-lqr"], cwd=world[0], env=_env(),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()
    err = p.communicate(timeout=60)[1]
    assert err == b"" and p.returncode == 141
    assert (snapshot(world[0]), snapshot(world[1])) == before


@pytest.mark.parametrize("argv", [["config", "dip-lqr"], ["list"]])
def test_full_disk_behind_stdout(world, argv):
    before = snapshot(world[0]), snapshot(world[1])
    with open("/dev/full", "w") as full:
        r = _child(argv, world[0], stdout=full)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: stdout: cannot write standard output: "
                                                               "No space left"), r.stderr
    assert (snapshot(world[0]), snapshot(world[1])) == before


def test_ascii_terminal(world):
    """LANG=C and an ASCII-only encoding: the config's non-ASCII text and an error echoing a non-ASCII value
    come out escaped, never as UnicodeEncodeError."""
    env = _env(LANG="C", LC_ALL="C", PYTHONIOENCODING="ascii")
    before = snapshot(world[0]), snapshot(world[1])
    r = _child(["config", "dip-lqr"], world[0], env=env)
    assert r.returncode == 0 and r.stderr == "" and "\\xa7" in r.stdout
    r = _child([*RUN, "--set", "seeds=\u00e9t\u00e9"], world[0], env=env)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: seeds: expected an integer, got '\\xe9t"), \
        r.stderr
    assert (snapshot(world[0]), snapshot(world[1])) == before


def test_deleted_working_folder(tmp_path):
    gone = tmp_path / "gone"
    gone.mkdir()
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "keep.txt").write_text("keep\n")
    before = snapshot(victim)
    script = f"cd {gone} && rmdir {gone} && exec {sys.executable} -m jaxdip.cli run dip-lqr --quick --out o"
    r = subprocess.run(["sh", "-c", script], env=_env(PYTHONPATH=ROOT), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: --out: a relative path, and the working "
                                                               "folder is gone"), r.stderr
    assert snapshot(victim) == before and not gone.exists()


def _vm_size_after_import() -> int:
    """The address space a ``jaxdip run`` uses once its experiments are imported (JAX's backend started)."""
    code = ("from jaxdip.runner import registry; registry()\n"
            "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmSize:')][0])")
    r = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=60)
    return int(r.stdout) * 1024


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="Linux's /proc")
def test_memory_limit_is_part_of_the_resource_check(world):
    """Under ``ulimit -v`` (RLIMIT_AS) a run that the machine's free memory would allow, but the limit would not,
    is refused before anything compiles, naming --seeds."""
    work, victim = world
    headroom = 768 << 20
    limit = _vm_size_after_import() + headroom
    cfg = dip_lqr.DipLqrConfig(**dip_lqr.EXPERIMENT.quick)
    (load,) = cfg.loads()
    per_seed = (load.saved + load.state) * FLOAT_BYTES * COPIES
    seeds = int(4 * headroom / per_seed)  # about 3 GiB: beyond the limit's headroom
    if seeds * per_seed > USABLE * available_bytes():
        pytest.skip("this machine has too little free memory to tell the limit from the machine")
    before = snapshot(work), snapshot(victim)
    script = f"ulimit -v {limit // 1024} && exec {sys.executable} -m jaxdip.cli {' '.join(RUN)} --seeds {seeds}"
    r = subprocess.run(["sh", "-c", script], cwd=work, env=_env(), capture_output=True, text=True, timeout=60)
    line = one_line(r.stderr)
    assert r.returncode == 2 and line.startswith("error: --seeds: the Monte Carlo"), r.stderr
    assert (snapshot(work), snapshot(victim)) == before


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
                         env=_env(), stderr=subprocess.PIPE, text=True)
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
    r = _child(_distributed(_closed_port(), 1, "--connect-timeout", "1"), work, timeout=60)
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
        r = _child(_distributed(busy.getsockname()[1], 0, "--connect-timeout", "5"), work, timeout=60)
    line = one_line(r.stderr)
    assert r.returncode == 2 and "is in use on this machine" in line, line
    assert (snapshot(work), snapshot(victim)) == before


def test_reproduce_refusal_starts_no_worker(world):
    """A bad --out is found before the worker processes start: the child has no children of its own."""
    work, victim = world
    code = ("import sys, subprocess\n"
            "from jaxdip import cli, reproduce_pool\n"
            "class NoWorkers:\n"
            "    def __init__(self, *a, **k):\n"
            "        print('worker started', file=sys.stderr); sys.exit(99)\n"
            "reproduce_pool.Workers = NoWorkers\n"
            "sys.exit(cli.main(['reproduce', '--quick', '--jobs', '2', '--out', 'notes.txt']))\n")
    before = snapshot(work), snapshot(victim)
    r = subprocess.run([sys.executable, "-c", code], cwd=work, env=_env(), capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: --out: notes.txt exists"), r.stderr
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
