"""lorenz-mhe: gradient w.r.t. gamma, determinism across batching, config file, a small end-to-end run."""

import jaxdip  # noqa: F401  (float64)

import json
import os
import subprocess
import sys
import time

import equinox as eqx
import jax
import numpy as np
import pytest

import jaxdip as jd
from jaxdip import config as C
import experiments.lorenz_mhe as L
from jaxdip.runner import get, run_experiment
from jaxdip.scenarios import lorenz_mhe as S

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _cpx_norm_error(sol):
    e = sol.metrics["errors"]
    return e["norm"][:, 0] / e["n"][:, 0]


def test_gradient_cpx_error_wrt_gamma():
    """d(mean CPX norm error)/d(gamma) by reverse mode through jd.monte_carlo agrees with central differences."""
    rollout = S.build(steps=300)
    key = jax.random.PRNGKey(3)

    def loss(g):
        return _cpx_norm_error(jd.monte_carlo(eqx.tree_at(S.gamma_of("cpx"), rollout, g), key, 1))[0]

    # one program: its value output gives the differences too (a separate jit of the loss compiled the loop again)
    vg = jax.jit(jax.value_and_grad(loss))
    g0 = 0.5
    ad = float(vg(g0)[1])
    dg = 1e-4 * g0
    fd = float((vg(g0 + dg)[0] - vg(g0 - dg)[0]) / (2 * dg))
    print(f"\nd e_CPX / d gamma at gamma = {g0}: autodiff {ad:.10g}, central FD {fd:.10g}, "
          f"rel {abs(ad - fd) / abs(fd):.1e}")
    assert abs(ad - fd) <= 1e-5 * abs(fd)
    assert abs(fd) > 1e-3  # the error does depend on gamma: the comparison is not 0 = 0


@pytest.mark.slow  # two more compiles of the four-estimator loop (~10 s); the DESIGN property, not an acceptance item
def test_trial_independent_of_batch():
    """Trial i gives the same numbers alone and inside a batch (keys are fold_in(base, i))."""
    rollout = S.build(steps=50)
    key = jax.random.PRNGKey(0)
    batch = jd.monte_carlo(rollout, key, 3, time_chunk=20).metrics["errors"]
    alone = jd.monte_carlo(rollout, key, 1, offset=2).metrics["errors"]
    for name in ("norm", "xl", "norm_cur"):
        np.testing.assert_allclose(np.asarray(alone[name][0]), np.asarray(batch[name][2]), rtol=1e-12)


def test_config_file_mirrors_defaults():
    cfg = C.load(L.LorenzMheConfig, path=os.path.join(ROOT, "configs", "lorenz-mhe.toml"))
    assert cfg == L.LorenzMheConfig()
    with pytest.raises(C.ConfigError) as e:
        C.load(L.LorenzMheConfig, sets=["scpx_p=4"])
    assert e.value.key == "scpx_p"
    for bad in ("-2", "3"):  # -1 (no record) or a trial of the run
        with pytest.raises(C.ConfigError) as e:
            C.load(L.LorenzMheConfig, sets=["seeds=3", f"record_seed={bad}"])
        assert e.value.key == "record_seed"


def test_small_run_writes_contract(tmp_path):
    exp = get("lorenz-mhe")
    cfg = C.load(exp.config_cls, sets=["seeds=4", "duration=0.3", "chunk_steps=100", "record_every=5"])
    metrics = run_experiment(exp, cfg, str(tmp_path / "out"))
    res = metrics["results"]
    for m in ("cpx", "scpx", "ekf", "ekf2"):
        for k in ("mean_norm_error", "mean_xL_error", "mean_norm_error_ci95", "mean_xL_error_ci95", "diverged"):
            assert k in res[m], (m, k)
        assert res[m]["diverged"] == 0
        assert 0 < res[m]["mean_norm_error"] < 20  # measurement noise std is 5: estimates do track the state
    files = set(os.listdir(tmp_path / "out"))
    assert {"metrics.json", "report.md", "config.toml", "errors_per_method.png", "xL_scpx_vs_ekf.png"} <= files
    with open(tmp_path / "out" / "metrics.json") as fh:
        assert json.load(fh)["experiment"] == "lorenz-mhe"


@pytest.mark.slow
def test_cli_quick_under_a_minute(tmp_path):
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "jaxdip.cli", "run", "lorenz-mhe", "--quick", "--out", str(tmp_path / "q")],
                   check=True, cwd=ROOT, env={**os.environ, "JAXDIP_NO_PROGRESS": "1"})
    wall = time.perf_counter() - t0
    print(f"\njaxdip run lorenz-mhe --quick: {wall:.1f} s")
    assert wall < 60
    assert np.isfinite(json.load(open(tmp_path / "q" / "metrics.json"))["results"]["scpx"]["mean_xL_error"])
