"""Recorded data: the CSV round trip is exact, ``jd.run_estimator`` follows the loop's input convention and
batches by vmap, and a loop's record, written and read back, is filtered offline by the EKF, UKF and CPX to the
loop's own estimates (docs/estimation.md's example, executed here)."""

import pathlib
import re

import equinox as eqx
import jax
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.engine.checks import ArgumentError
from jaxdip.estimators import KalmanFilter
from jaxdip.runner import records
from jaxdip.scenarios import lorenz_mhe

DOC = pathlib.Path(__file__).resolve().parents[1] / "docs" / "estimation.md"


def test_csv_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    rec = {"t": np.arange(7) * 0.1, "y": rng.normal(size=(7, 3)) * 10.0 ** rng.integers(-300, 300, size=(7, 3)),
           "x.a": rng.normal(size=(7, 1)), "tiny": np.full(7, 5e-324), "big": np.full(7, -1.7976931348623157e308)}
    records.write_csv(tmp_path / "r.csv", rec)
    back = records.read_csv(tmp_path / "r.csv")
    assert list(back) == list(rec)
    for k, v in rec.items():
        assert back[k].shape == v.shape and np.array_equal(back[k], v), k


def test_csv_refuses_ragged_columns_and_bad_names(tmp_path):
    with pytest.raises(ArgumentError, match="has 3 rows"):
        records.write_csv(tmp_path / "r.csv", {"a": np.zeros(4), "b": np.zeros(3)})
    with pytest.raises(ArgumentError, match="column names"):
        records.write_csv(tmp_path / "r.csv", {"a[0]": np.zeros(4)})


def _numpy_kf(Phi, W, C, Q, R, P0, m0, ys, us):
    """x_{k+1} = Phi x_k + W u_k + w_k, y_k = C x_k + v_k; (m0, P0) the prior of x_0: filtered means."""
    m, P, out = m0.copy(), P0.copy(), []
    for k in range(len(ys)):
        if k > 0:
            m, P = Phi @ m + W @ us[k - 1], Phi @ P @ Phi.T + Q
        S = C @ P @ C.T + R
        K = np.linalg.solve(S, C @ P).T
        m, P = m + K @ (ys[k] - C @ m), P - K @ S @ K.T
        out.append(m)
    return np.array(out)


def test_run_estimator_takes_applied_inputs_and_batches():
    rng = np.random.default_rng(1)
    Phi = np.array([[1.0, 0.1], [-0.1, 0.98]])
    W, C = np.array([[0.0], [0.1]]), np.array([[1.0, 0.0]])
    Q, R, P0, m0 = 0.01 * np.eye(2), np.eye(1), np.eye(2), np.array([0.5, -0.5])
    kf = KalmanFilter(Phi, W, C, Q, R, P0, m0)
    ys, us = rng.normal(size=(3, 40, 1)), rng.normal(size=(3, 40, 1))
    batch = jd.run_estimator(kf, ys, us)
    assert batch.xhat.shape == (3, 40, 2) and batch.aux.cov.shape == (3, 40, 2, 2)
    for b in range(3):
        ref = _numpy_kf(Phi, W, C, Q, R, P0, m0, ys[b], us[b])
        np.testing.assert_allclose(batch.xhat[b], ref, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(batch.xhat[b], jd.run_estimator(kf, ys[b], us[b]).xhat)
    with pytest.raises(ArgumentError, match=r"us must be \(B, T, m\)"):
        jd.run_estimator(kf, ys, us[0])
    with pytest.raises(ArgumentError, match="ys must be"):
        jd.run_estimator(kf, ys[0, :, 0])


def doc_example() -> str:
    text = DOC.read_text()
    m = re.search(r"<!-- executed by tests/test_records.py -->\n```python\n(.*?)^```", text, re.S | re.M)
    assert m, "the recorded-data example of docs/estimation.md is missing"
    return m.group(1)


def test_loop_record_filtered_offline_equals_the_loop(tmp_path, capsys):
    """The docs' example on a short record of the lorenz-mhe loop (seed 3, 100 samples): EKF, UKF and CPX from
    the CSV equal their in-loop estimates to 1e-12 (they are equal bit for bit). The loop keeps only those three
    members (one compile less each: every member gets the same keys, so their numbers are the full loop's)."""
    rollout = lorenz_mhe.build(steps=100, ukf=True)
    fan = rollout.loop.estimator
    rollout = eqx.tree_at(lambda r: r.loop.estimator, rollout,
                          jd.FanOut({k: fan.estimators[k] for k in ("ekf", "ukf", "cpx")}, drive="ekf"))
    rec = records.loop_record(rollout, jax.random.fold_in(jax.random.PRNGKey(0), 3))
    assert rec["y"].shape == (100, 2) and rec["x"].shape == (100, 3) and "xhat.scpx" not in rec
    assert {"xhat.ekf", "xhat.ukf", "xhat.cpx"} <= set(rec)
    # the three are different estimates, so equality below is not of one number thrice
    assert np.abs(rec["xhat.ekf"] - rec["xhat.ukf"]).max() > 1e-6 and np.abs(rec["xhat.ekf"] - rec["xhat.cpx"]).max() > 1e-3
    path = tmp_path / "record-seed3.csv"
    records.write_csv(path, rec)
    code = doc_example().replace('path = "lorenz/record-seed0.csv"', f"path = {str(path)!r}")
    assert str(path) in code
    exec(compile(code, f"{DOC}:recorded-example", "exec"), {"__name__": "doc"})
    printed = capsys.readouterr().out
    for name in ("ekf", "ukf", "cpx"):
        assert f"{name}: recorded-data run vs in-loop estimate" in printed


@pytest.mark.slow
def test_jaxdip_run_record_filtered_offline_equals_the_loop(tmp_path, capsys):
    """The same on the CSV that `jaxdip run lorenz-mhe --quick --set record_seed=0` writes (2000 samples)."""
    from jaxdip.cli import main

    out = tmp_path / "lorenz"
    assert main(["run", "lorenz-mhe", "--quick", "--set", "record_seed=0", "--out", str(out)]) in (0, None)
    code = doc_example().replace('path = "lorenz/record-seed0.csv"', f"path = {str(out / 'record-seed0.csv')!r}")
    exec(compile(code, f"{DOC}:recorded-example", "exec"), {"__name__": "doc"})
    assert capsys.readouterr().out.count("recorded-data run vs in-loop estimate") == 3
