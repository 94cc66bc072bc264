"""The workers of a parallel ``jaxdip reproduce`` are forked from the command's process when nothing has started
JAX's backend there (they then skip the import of JAX and the experiments); a process that has computed starts
them as new interpreters. Importing the library and every experiment computes nothing."""

import json
import os
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import pytest

from jaxdip import reproduce_pool

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only")


def _child(code: str, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, JAXDIP_NO_PROGRESS="1", **env), timeout=300)


def test_importing_every_experiment_leaves_the_backend_unstarted():
    """XLA reads its flags when the backend starts: flags set after the imports must still count (a module-level
    array would start the backend at import, with one device here)."""
    r = _child("""
        import os
        import jaxdip
        from jaxdip.runner import registry
        assert len(registry()) > 10
        os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=3"
        import jax
        print(jax.device_count())
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["3"]


@linux_only
def test_forked_workers_run_tasks_in_their_own_sessions_and_end_at_end_of_input(tmp_path):
    r = _child(f"""
        import json, os, queue
        from jaxdip import reproduce_pool as rp
        assert rp.can_fork()
        pool = rp.Workers(2)
        assert all(isinstance(w["proc"], rp.Forked) for w in pool.workers)
        for i, w in enumerate(pool.workers):
            w["given"] = True  # as run_parallel marks it: close() waits for such a worker instead of killing it
            w["proc"].stdin.write(json.dumps({{"id": str(i), "argv": ["config", "dip-lqr"],
                                               "log": os.path.join({str(tmp_path)!r}, f"{{i}}.log")}}) + "\\n")
        answers = sorted(pool.answers.get(timeout=120)[1]["id"] for _ in range(2))
        pids = [w["proc"].pid for w in pool.workers]
        sessions = [os.getsid(p) == p for p in pids]
        cpus = [sorted(os.sched_getaffinity(p)) for p in pids]
        pool.close()  # end of input to the first worker too: the second must not hold its pipe open
        print(json.dumps({{"answers": answers, "sessions": sessions, "cpus": cpus,
                          "codes": [w["proc"].returncode for w in pool.workers]}}))
    """)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got["answers"] == ["0", "1"] and got["sessions"] == [True, True] and got["codes"] == [0, 0]
    blocks = reproduce_pool.cpu_blocks(2)
    if blocks:  # each worker kept to its own CPUs, as a started worker is
        assert got["cpus"] == blocks
    expected = subprocess.run([sys.executable, "-m", "jaxdip.cli", "config", "dip-lqr"], capture_output=True,
                              text=True, cwd=ROOT).stdout
    assert expected and all((tmp_path / f"{i}.log").read_text() == expected for i in range(2))


def test_a_process_that_has_computed_starts_its_workers_afresh():
    assert float(jnp.ones(2).sum()) == 2.0  # the backend is running in this process now
    assert not reproduce_pool.can_fork()
