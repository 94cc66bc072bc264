"""``--distributed``: Monte Carlo over the devices of several processes (``jax.distributed``, gloo collectives on
CPU) gives the single-process numbers; bad values are one-line errors.

The multi-process runs are real: two local processes, each with two XLA host devices, joined through a
coordinator on a free localhost port. The reference is the same computation in one process. The CLI run on
two processes (only process 0 writes) is in test_cli.py, beside the one-process run it is compared with.
"""

import os
import socket
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from jaxdip import distributed
from conftest import host_devices_flags

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.dirname(os.path.abspath(__file__))
# cluster variables of the machine running the tests must not leak into the "nothing detected" cases
CLUSTER_VARS = ("SLURM_", "OMPI_", "PMI_", "JAX_COORDINATOR", "JAXDIP_COORDINATOR", "JAXDIP_NUM_PROCESSES",
                "JAXDIP_PROCESS_ID", "TPU_")


def clean_env(**extra):
    env = {k: v for k, v in os.environ.items() if not k.startswith(CLUSTER_VARS)}
    env.update(JAX_PLATFORMS="cpu", XLA_FLAGS=host_devices_flags(2), **extra)
    return env


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch_pair(make_cmd, timeout=600, **env_extra):
    """Start processes 0 and 1 (``make_cmd(process_id, port)``), wait for both; [(rc, stdout, stderr)] ."""
    port = free_port()
    procs = [subprocess.Popen(make_cmd(i, port), cwd=ROOT, env=clean_env(**env_extra), stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for i in (0, 1)]
    try:
        outs = [p.communicate(timeout=timeout) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    return [(p.returncode, o, e) for p, (o, e) in zip(procs, outs)]


# ---- the values: flags, then JAXDIP_ variables, then the cluster's ------------------------------------------


def test_flags_win_over_environment_and_fill_in_separately():
    env = {"JAXDIP_COORDINATOR": "node7:1234", "JAXDIP_NUM_PROCESSES": "4", "JAXDIP_PROCESS_ID": "3"}
    assert distributed.resolve(environ=env) == {"coordinator": "node7:1234", "num_processes": 4, "process_id": 3}
    assert distributed.resolve("head:99", None, 1, environ=env) == {
        "coordinator": "head:99", "num_processes": 4, "process_id": 1}
    assert distributed.resolve(environ={}) == {"coordinator": None, "num_processes": None, "process_id": None}
    assert distributed.resolve("[::1]:8476", 2, 0, environ={})["coordinator"] == "[::1]:8476"


@pytest.mark.parametrize("kw, env, match", [
    (dict(coordinator="node7"), {}, "--coordinator: expected HOST:PORT"),
    (dict(coordinator="node7:0"), {}, "--coordinator: expected HOST:PORT"),
    (dict(coordinator="node7:70000"), {}, "--coordinator: expected HOST:PORT"),
    ({}, {"JAXDIP_COORDINATOR": "a b:12"}, "JAXDIP_COORDINATOR: expected HOST:PORT"),
    (dict(num_processes="two"), {}, "--num-processes: expected an integer"),
    (dict(num_processes=0), {}, "--num-processes: must be between 1 and"),
    (dict(num_processes=10**30), {}, "--num-processes: must be between 1 and"),
    ({}, {"JAXDIP_PROCESS_ID": "-1"}, "JAXDIP_PROCESS_ID: must be >= 0"),
    (dict(num_processes=2, process_id=2), {}, r"--process-id: must be below the number of processes \(2\)"),
    (dict(process_id=5), {"JAXDIP_NUM_PROCESSES": "4"}, "--process-id: must be below"),
])
def test_invalid_values_name_where_they_came_from(kw, env, match):
    with pytest.raises(distributed.DistributedError, match=match):
        distributed.resolve(environ=env, **kw)


def jaxdip_cli(*args, **env):
    return subprocess.run([sys.executable, "-m", "jaxdip.cli", *args], cwd=ROOT, env=clean_env(**env),
                          capture_output=True, text=True, timeout=300)


def cli_in_process(argv, monkeypatch, capsys, **env):
    """``jaxdip`` in this process (no JAX start-up per case), with clean_env's variables: (exit code, stderr)."""
    from jaxdip import cli

    for k in list(os.environ):
        if k.startswith(CLUSTER_VARS):
            monkeypatch.delenv(k)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    capsys.readouterr()
    code = cli.main(argv)
    return code, capsys.readouterr().err


@pytest.mark.parametrize("args, env, start", [
    (["--distributed", "--num-processes", "0"], {}, "error: --distributed: --num-processes: must be between 1 and"),
    (["--distributed", "--coordinator", "localhost"], {}, "error: --distributed: --coordinator: expected HOST:PORT"),
    (["--distributed"], {"JAXDIP_PROCESS_ID": "x"}, "error: --distributed: JAXDIP_PROCESS_ID: expected an integer"),
    (["--process-id", "1"], {}, "error: --process-id: only with --distributed"),
])
def test_cli_errors_are_one_line_exit_2_and_write_nothing(tmp_path, monkeypatch, capsys, args, env, start):
    """Values refused before ``jax.distributed`` is called, so checked in this process."""
    out = tmp_path / "o"
    code, err = cli_in_process(["run", "dip-lqr", "--quick", "--out", str(out), *args], monkeypatch, capsys, **env)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith(start), err
    assert not out.exists()


def test_cli_no_cluster_detected_is_one_line_exit_2(tmp_path):
    """Found out by ``jax.distributed.initialize`` itself, which must run before any JAX computation: a child."""
    out = tmp_path / "o"
    r = jaxdip_cli("run", "dip-lqr", "--quick", "--out", str(out), "--distributed")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: --distributed: no cluster detected"), \
        r.stderr
    assert not out.exists()


def test_reproduce_distributed_runs_experiments_in_turn(tmp_path, monkeypatch, capsys):
    code, err = cli_in_process(["reproduce", "--quick", "--out", str(tmp_path / "o"), "--distributed", "--jobs", "2"],
                               monkeypatch, capsys)
    assert code == 2 and err.startswith("error: --jobs: --distributed runs"), err
    assert not (tmp_path / "o").exists()


# ---- monte_carlo over two processes ---------------------------------------------------------------------------

MC_SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    from jaxdip import distributed
    pid, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    if pid >= 0:
        distributed.initialize(f"127.0.0.1:{port}", 2, pid)
    import jax, jax.numpy as jnp
    import jaxdip as jd
    from test_distributed import lorenz_rollout, noise_and_index, first_half

    if pid >= 0:
        assert jax.process_count() == 2 and jax.device_count() == 4, jax.devices()
    r = lorenz_rollout()
    key = jax.random.PRNGKey(11)
    runs = {
        # 13 seeds over 4 devices: padded to 16, the horizon in 3 calls (state carried across processes)
        "chunked": jd.monte_carlo(r, key, 13, time_chunk=8, progress=True),
        "index": jd.monte_carlo(noise_and_index, key, 9, index=True, detail=first_half),
        # two calls of 8 seeds (one padded), then a sweep over the noise level, one program
        "seeds": jd.monte_carlo(r, key, 13, chunk=6, offset=5),
        "sweep": jd.monte_carlo(r, key, 6, sweep=(lambda r: r.loop.sensor.std, jnp.array([0.1, 2.0]))),
    }
    leaves = jax.tree_util.tree_leaves(runs)
    assert all(a.is_fully_addressable for a in leaves)  # gathered: plain arrays on this process
    np.savez(out, *[np.asarray(a) for a in leaves])
    """
)


def save_y(s):
    return s.y


def meas_error(s):
    return s.y - s.x


def lorenz_rollout():
    """A cheap closed loop (Lorenz, 3 states, one RK4 step a period) that compiles in about a second."""
    import jax.numpy as jnp

    import jaxdip as jd
    from jaxdip.engine import Gaussian

    loop = jd.Loop(plant=jd.plants.Lorenz(), sensor=jd.sensors.WhiteNoise(jnp.array(0.5)),
                   estimator=jd.Passthrough(), controller=jd.control.ConstantInput(jnp.zeros(1)), dt=0.01,
                   substeps=1, process_noise_std=0.01)
    metrics = {"x": jd.metrics.Moments("x"), "err": jd.metrics.RMS(meas_error)}
    return jd.Rollout(loop, Gaussian(jnp.array([1.0, 1.0, 20.0]), 0.5), 24, save=save_y, save_every=2,
                      metrics=metrics)


def noise_and_index(key, i):
    import jax

    return jax.random.normal(key, (4,)) * (1.0 + i)


def first_half(out):
    return out[:2], out[2:]


@pytest.mark.slow  # 30-65 s on 2 busy cores: the CLI test below is the default suite's two-process check
def test_monte_carlo_over_two_processes_equals_one_process(tmp_path):
    # the script imports this module: the tests folder on the children's PYTHONPATH
    res = launch_pair(lambda i, port: [sys.executable, "-c", MC_SCRIPT, str(i), str(port),
                                       str(tmp_path / f"p{i}.npz")], timeout=300, PYTHONPATH=HERE)
    for i, (rc, _, err) in enumerate(res):
        assert rc == 0, f"process {i}:\n{err[-3000:]}"
    single = subprocess.run([sys.executable, "-c", MC_SCRIPT, "-1", "0", str(tmp_path / "one.npz")],
                            cwd=ROOT, env=clean_env(PYTHONPATH=HERE), capture_output=True, text=True, timeout=300)
    assert single.returncode == 0, single.stderr[-3000:]
    one, p0, p1 = (np.load(tmp_path / f) for f in ("one.npz", "p0.npz", "p1.npz"))
    assert len(one.files) == len(p0.files) > 10
    for name in one.files:
        a, b, c = one[name], p0[name], p1[name]
        np.testing.assert_array_equal(b, c)  # every process holds the whole, same result
        assert a.shape == b.shape and a.dtype == b.dtype
        if a.dtype.kind in "biu":
            np.testing.assert_array_equal(a, b)
        else:
            # same seeds, other batch shapes: equal to rounding (see test_driver.assert_same)
            assert np.max(np.abs(a - b), initial=0.0) <= 1e-12 * np.max(np.abs(a), initial=0.0), name


# ---- used by the CLI's two-process run (test_cli.py) and test_spread.py -------------------------------------------

def compare_results(a, b, path="results"):
    """Largest relative difference between two metrics.json result trees (structure and non-floats equal)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        return max([compare_results(a[k], b[k], f"{path}.{k}") for k in a], default=0.0)
    if isinstance(a, list):
        assert len(a) == len(b), path
        return max([compare_results(u, v, f"{path}[{i}]") for i, (u, v) in enumerate(zip(a, b))], default=0.0)
    if isinstance(a, float) and isinstance(b, float):
        return 0.0 if a == b else abs(a - b) / max(abs(a), abs(b))
    assert a == b, (path, a, b)
    return 0.0
