"""Faults of every class the command line promises to stop cleanly on: exit status, exactly one line on standard
error of at most 300 characters with no raw control character, and the working folder and a victim folder
beside it left exactly as they were (``snapshots.snapshot``).

The table runs in this process (nothing in it compiles); what needs a real process (a closed pipe, a FIFO, an
ASCII-only terminal, a memory limit, a deleted working folder) runs as a child; ``--distributed``'s faults are
in test_cli_distributed_faults.py.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import os
import socket
import subprocess
import sys
import warnings

import pytest

from jaxdip import cli, reproduce_pool
import experiments.dip_lqr as dip_lqr
from jaxdip.resources import FLOAT_BYTES, COPIES, USABLE, available_bytes
from cli_faults_support import RUN, child_env, make_world, one_line, run_child
from snapshots import snapshot

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LONG = "x" * 100_000
ESC = "\x1b]0;owned\x07\x1b[2J"  # a terminal title change and a screen clear


@pytest.fixture
def world(tmp_path, monkeypatch):
    return make_world(tmp_path, monkeypatch)


def _sock(path):
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(path))
    return s


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


def test_numpy_warning_before_a_late_refusal(world):
    """R = 1e308: NumPy warns of an overflow in the Riccati design, which then fails: one line, not the warning's
    two and the error's one."""
    work, victim = world
    before = snapshot(work), snapshot(victim)
    r = run_child([*RUN, "--set", "R=1e308"], work)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: Q, R: cannot solve the CARE"), r.stderr
    assert (snapshot(work), snapshot(victim)) == before


def test_fifo_config_does_not_hang(world):
    work, victim = world
    before = snapshot(work), snapshot(victim)
    r = run_child([*RUN, "--config", "fifo.toml"], work, timeout=30)
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
    r = run_child(argv, work, timeout=30)
    assert r.returncode == 2 and "is a FIFO" in one_line(r.stderr), r.stderr
    assert (snapshot(work), snapshot(victim)) == before


def test_closed_pipe_exits_quietly(world):
    """``jaxdip config dip-lqr | head -0``: the reader is gone before the first write."""
    before = snapshot(world[0]), snapshot(world[1])
    p = subprocess.Popen([sys.executable, "-m", "jaxdip.cli", "config", "dip-lqr"], cwd=world[0], env=child_env(),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()
    err = p.communicate(timeout=60)[1]
    assert err == b"" and p.returncode == 141
    assert (snapshot(world[0]), snapshot(world[1])) == before


@pytest.mark.parametrize("argv", [["config", "dip-lqr"], ["list"]])
def test_full_disk_behind_stdout(world, argv):
    before = snapshot(world[0]), snapshot(world[1])
    with open("/dev/full", "w") as full:
        r = run_child(argv, world[0], stdout=full)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: stdout: cannot write standard output: "
                                                               "No space left"), r.stderr
    assert (snapshot(world[0]), snapshot(world[1])) == before


def test_ascii_terminal(world):
    """LANG=C and an ASCII-only encoding: the config's non-ASCII text and an error echoing a non-ASCII value
    come out escaped, never as UnicodeEncodeError."""
    env = child_env(LANG="C", LC_ALL="C", PYTHONIOENCODING="ascii")
    before = snapshot(world[0]), snapshot(world[1])
    r = run_child(["config", "dip-lqr"], world[0], env=env)
    assert r.returncode == 0 and r.stderr == "" and "\\xa7" in r.stdout
    r = run_child([*RUN, "--set", "seeds=\u00e9t\u00e9"], world[0], env=env)
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
    r = subprocess.run(["sh", "-c", script], env=child_env(PYTHONPATH=ROOT), capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: --out: a relative path, and the working "
                                                               "folder is gone"), r.stderr
    assert snapshot(victim) == before and not gone.exists()


def _vm_size_after_import() -> int:
    """The address space a ``jaxdip run`` uses once its experiments are imported (JAX's backend started)."""
    code = ("import jax\nfrom jaxdip.runner import registry; registry(); jax.devices()\n"
            "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmSize:')][0])")
    r = subprocess.run([sys.executable, "-c", code], env=child_env(), capture_output=True, text=True, timeout=60)
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
    r = subprocess.run(["sh", "-c", script], cwd=work, env=child_env(), capture_output=True, text=True, timeout=60)
    line = one_line(r.stderr)
    assert r.returncode == 2 and line.startswith("error: --seeds: the Monte Carlo"), r.stderr
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
    r = subprocess.run([sys.executable, "-c", code], cwd=work, env=child_env(), capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and one_line(r.stderr).startswith("error: --out: notes.txt exists"), r.stderr
    assert (snapshot(work), snapshot(victim)) == before
