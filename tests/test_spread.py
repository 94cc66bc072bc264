"""The ensemble split by member over processes (``jax.distributed``, ``--distributed``): two local processes
with two XLA host devices each (members in four blocks, gathered through gloo) give the one-process search
(one process, two devices) to 1e-12; a split that does not divide the ensemble is a clear error.

The split over one process's devices is tested in test_eki.py."""

import json
import sys
import textwrap

import jax
import numpy as np
import pytest

from jaxdip.engine.checks import ArgumentError
from jaxdip.search import spread
from test_distributed import ROOT, clean_env, compare_results, launch_pair

# a small nonlinear search with per-member keys (each device's block must fold its own members' indices):
# 3 chunks, every iteration gathers the blocks
EKI_SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    from jaxdip import distributed
    pid, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    if pid >= 0:
        distributed.initialize(f"127.0.0.1:{port}", 2, pid)
    import jax, jax.numpy as jnp
    from jaxdip.search import EKI, run_eki
    from jaxdip.search.spread import member_devices

    A = jnp.array([[1.0, 2.0, 0.5], [0.3, -1.0, 2.0]])

    def G(v, key):
        return A @ jnp.tanh(v) + 0.01 * jax.random.normal(key, (2,))

    eki = EKI(G=G, template=jnp.zeros(3), y_target=jnp.array([1.0, -0.5]), R=0.1 * jnp.eye(2), member_keys=True)
    st = eki.init(jax.random.normal(jax.random.PRNGKey(0), (8, 3)), jax.random.PRNGKey(1))
    devices = member_devices(8)
    st, hist = run_eki(eki, st, 7, chunk=3)
    assert st.members.is_fully_addressable  # handed back as this process's arrays
    np.savez(out, members=np.asarray(st.members), hist=hist, devices=len(devices),
             processes=len({d.process_index for d in devices}))
    """
)


def test_two_processes_split_the_members_and_give_the_one_process_search(tmp_path):
    res = launch_pair(lambda i, port: [sys.executable, "-c", EKI_SCRIPT, str(i), str(port),
                                       str(tmp_path / f"p{i}.npz")], timeout=300)
    for i, (rc, _, err) in enumerate(res):
        assert rc == 0, f"process {i}:\n{err[-3000:]}"
    import subprocess

    single = subprocess.run([sys.executable, "-c", EKI_SCRIPT, "-1", "0", str(tmp_path / "one.npz")], cwd=ROOT,
                            env=clean_env(), capture_output=True, text=True, timeout=300)
    assert single.returncode == 0, single.stderr[-3000:]
    one, p0, p1 = (np.load(tmp_path / f) for f in ("one.npz", "p0.npz", "p1.npz"))
    assert int(p0["devices"]) == 4 and int(p0["processes"]) == 2  # the split spans both processes
    assert int(one["devices"]) == 2 and int(one["processes"]) == 1
    for name in ("members", "hist"):
        np.testing.assert_array_equal(p0[name], p1[name])  # every process holds the same ensemble
        scale = np.max(np.abs(one[name]))
        assert scale > 0.1 and np.max(np.abs(one[name] - p0[name])) <= 1e-12 * scale, name


@pytest.mark.slow  # about 2 minutes on 2 busy cores (three eki-dip --quick runs); the test above is the default one
def test_eki_dip_quick_on_two_processes_gives_the_one_process_P(tmp_path):
    """The acceptance check: ``jaxdip run eki-dip --quick --distributed`` on two processes (4 devices, the 8
    members in blocks of 2) against one process (2 devices): the found P (basis, singular values) to 1e-12
    (measured: identical), every other result to 1e-10. Without the variant table: its UKI reading moves 29
    sigma points, which no split over 4 devices divides (refused, as it should be)."""
    import subprocess

    run = [sys.executable, "-m", "jaxdip.cli", "run", "eki-dip", "--quick", "--no-compile-cache", "--set",
           "variants_table=false"]
    env = clean_env(JAXDIP_NO_PROGRESS="1")
    single = subprocess.run([*run, "--out", str(tmp_path / "one")], cwd=ROOT, env=env, capture_output=True,
                            text=True, timeout=600)
    assert single.returncode == 0, single.stderr[-3000:]
    res = launch_pair(lambda i, port: [*run, "--out", str(tmp_path / f"d{i}"), "--distributed", "--coordinator",
                                       f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(i)],
                      JAXDIP_NO_PROGRESS="1")
    for i, (rc, _, err) in enumerate(res):
        assert rc == 0, f"process {i}:\n{err[-3000:]}"
    m_one = json.loads((tmp_path / "one" / "metrics.json").read_text())
    m_dist = json.loads((tmp_path / "d0" / "metrics.json").read_text())
    assert m_dist["processes"] == 2 and m_dist["devices"] == 4
    P = ("P_basis", "P_singular_values")
    worst_P = compare_results({k: m_dist["results"][k] for k in P}, {k: m_one["results"][k] for k in P})
    worst = compare_results(m_dist["results"], m_one["results"])
    print(f"largest relative difference: P {worst_P:.3g}, all results {worst:.3g}")
    # the rest includes the judges' Monte Carlo statistics (split over 4 devices instead of 2 by monte_carlo),
    # whose CI bounds near 0 carry the reductions' rounding (measured: 8.9e-12 relative, 7e-18 absolute)
    assert worst_P <= 1e-12 and worst <= 1e-10


def test_a_split_that_does_not_divide_the_ensemble_is_refused(monkeypatch):
    three = [jax.local_devices()[0]] * 3
    monkeypatch.setattr(jax, "local_devices", lambda: three)
    assert spread.member_devices(6) == three  # several that divide J: split by default
    assert spread.member_devices(7) is None  # they do not divide J: no split by default
    assert spread.member_devices(6, shard=False) is None
    with pytest.raises(ArgumentError, match=r"its size \(7\) must be a multiple of the number of devices \(3"):
        spread.member_devices(7, shard=True)


def test_by_member_without_a_split_is_the_forward_model():
    import jax.numpy as jnp

    V = jnp.arange(12.0).reshape(4, 3)
    Y = spread.by_member(lambda V, key, first: V.sum(axis=1, keepdims=True) + first)(V, None)
    np.testing.assert_array_equal(np.asarray(Y), np.asarray(V).sum(axis=1, keepdims=True))
    assert spread.to_local(Y) is Y


# tune over an mc_objective of 5 seeds: blocks of 3 and 2 seeds on the two processes, gradients gathered
TUNE_SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    from jaxdip import distributed
    pid, port, out = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    if pid >= 0:
        distributed.initialize(f"127.0.0.1:{port}", 2, pid)
    import equinox as eqx
    import jax, jax.numpy as jnp
    from jaxdip.tune import mc_objective, tune

    class Trial(eqx.Module):
        theta: jax.Array

        def __call__(self, key):
            x = jax.random.normal(key, (2,))
            return jnp.sum((jnp.tanh(self.theta) - x) ** 2) + 0.1 * jnp.sum(self.theta ** 4)

    obj = mc_objective(Trial, [0, 1, 2, 5, 6])
    res = tune(obj, jnp.array([1.0, -2.0]), jax.random.PRNGKey(3), steps=6, lr=0.2, progress=False)
    part = obj.share(max(pid, 0), 2 if pid >= 0 else 1)
    np.savez(out, theta=np.asarray(res.theta), loss=res.loss_history, grad=res.grad_norm_history,
             seeds=np.asarray(part[0].seeds), weight=part[1])
    """
)


def test_tune_splits_an_mc_objectives_seeds_over_two_processes(tmp_path):
    import subprocess

    res = launch_pair(lambda i, port: [sys.executable, "-c", TUNE_SCRIPT, str(i), str(port),
                                       str(tmp_path / f"p{i}.npz")], timeout=300)
    for i, (rc, _, err) in enumerate(res):
        assert rc == 0, f"process {i}:\n{err[-3000:]}"
    single = subprocess.run([sys.executable, "-c", TUNE_SCRIPT, "-1", "0", str(tmp_path / "one.npz")], cwd=ROOT,
                            env=clean_env(), capture_output=True, text=True, timeout=300)
    assert single.returncode == 0, single.stderr[-3000:]
    one, p0, p1 = (np.load(tmp_path / f) for f in ("one.npz", "p0.npz", "p1.npz"))
    assert p0["seeds"].tolist() == [0, 1, 2] and p1["seeds"].tolist() == [5, 6]
    assert float(p0["weight"]) == 0.6 and float(p1["weight"]) == 0.4
    for name in ("theta", "loss", "grad"):
        np.testing.assert_array_equal(p0[name], p1[name])
        scale = np.max(np.abs(one[name]))
        assert scale > 0.1 and np.max(np.abs(one[name] - p0[name])) <= 1e-12 * scale, name
    assert one["loss"][-1] < one["loss"][0]  # it tunes


def test_objective_share_splits_the_seeds_into_weighted_blocks():
    import jax.numpy as jnp

    from jaxdip.tune import Objective, mc_objective

    obj = mc_objective(lambda th: (lambda key: th * jax.random.uniform(key)), [0, 1, 2, 5, 6, 9, 10])
    parts = [obj.share(i, 3) for i in range(3)]
    assert [p.seeds for p, _ in parts] == [[0, 1, 2], [5, 6], [9, 10]]
    theta, key = jnp.asarray(2.0), jax.random.PRNGKey(0)
    total = sum(w * float(p(theta, key)) for p, w in parts)
    assert abs(total - float(obj(theta, key))) <= 1e-14
    assert obj.share(7, 8) == (None, 0.0)  # fewer seeds than blocks: an empty block
    with pytest.raises(ValueError, match="does not know its seeds"):
        Objective(lambda th, k: th).share(0, 2)
