"""The bench's references: the NumPy DIP (an independent transcription) and the integration errors against
SciPy's DOP853 at tight tolerance, on the fixed noise sequence the bench uses."""

import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.bench.scoreboard import integration_errors, numpy_dip_f, numpy_dip_params, numpy_loop, scipy_loop


def test_numpy_dip_equals_the_jax_model():
    rng = np.random.default_rng(0)
    plant = jd.plants.DIP()
    for _ in range(20):
        x = rng.uniform(-1, 1, 6) * np.array([0.5, 1.0, 1.0, 2.0, 5.0, 5.0])
        V = rng.uniform(-5, 5)
        ref = numpy_dip_f(numpy_dip_params(), x, V)
        got = np.asarray(plant.vector_field(jnp.asarray(x), jnp.asarray([V])))
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))


def test_integration_errors_against_dop853():
    """200 periods of the dip-lqr loop on seed 0's noise: jaxdip's RK4 x 10 and the NumPy RK4 x 10 agree with
    DOP853 (rtol 1e-12) to 1e-12, one RK4 step per period to 1e-9 (the bench's default integration), with the
    DIP's vectorised sin/cos (dip-lqr's) and with the C library's."""
    e = integration_errors(substeps=(1, 10), n=200)["max_abs_final_state_error"]
    assert e["jaxdip_rk4x10"] < 1e-12 and e["numpy_rk4x10"] < 1e-12
    assert 1e-15 < e["jaxdip_rk4x1"] < 1e-9  # nonzero: the references do see the step size
    assert e["scipy_rk45"] < 1e-6
    assert 1e-15 < e["jaxdip_rk4x1_library_trig"] < 1e-9
    # with the float32 draw the reference replays the normals as saved, which XLA may round once differently from
    # the loop's in a few % of draws (docs/performance.md): ~1e-9 after 200 periods, 1.5e-12 after the bench's
    # 6500, as the stable loop forgets
    assert 1e-15 < e["jaxdip_rk4x1_float32_draw"] < 1e-8


def test_numpy_and_scipy_loops_agree_on_a_noise_sequence():
    K = np.asarray(jd.control.lqr(*jd.linearize(jd.plants.DIP()), np.diag([30.0, 350, 100, 0, 0, 0]), 0.1)[0])
    noise = np.random.default_rng(1).standard_normal((50, 6)) * 1e-3
    x0 = np.full(6, 0.01)
    a = numpy_loop(K, noise, x0, 0.001, 10)
    b = scipy_loop(K, noise, x0, 0.001, method="DOP853", rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(a - b)) < 1e-12 and np.max(np.abs(a - x0)) > 1e-4



def test_batch_sweep_rates_are_periods_over_time(tmp_path):
    """The GPU/CPU sweep's rate is batch x periods / seconds of a call, for each batch asked, on a tiny budget."""
    import json

    import pytest

    from jaxdip.bench import batch_sweep

    out = tmp_path / "s.json"
    assert batch_sweep.main(["1,3", "--out", str(out), "--budget", "0.01"]) == 0
    res = json.loads(out.read_text())
    assert res["x64"] is True and set(res["rates"]) == {"1", "3"}
    for b, r in res["rates"].items():
        assert r["periods"] >= 100
        assert r["periods_per_s"] == pytest.approx(int(b) * r["periods"] / r["s"], rel=1e-12)


def test_batch_sweep_float32_runs_the_float32_loop(tmp_path, monkeypatch):
    """``--precision float32`` times the loop with every period in float32: the final states it computes are
    float32 (the float64 run's are float64), and the file records the precision."""
    import json

    import jax.numpy as jnp

    from jaxdip.bench import batch_sweep

    seen = []
    real = batch_sweep.monte_carlo
    monkeypatch.setattr(batch_sweep, "monte_carlo", lambda r, key, b: seen.append(real(r, key, b)) or seen[-1])
    out = tmp_path / "s32.json"
    assert batch_sweep.main(["2", "--out", str(out), "--budget", "0.01", "--precision", "float32"]) == 0
    assert json.loads(out.read_text())["precision"] == "float32"
    assert seen and all(s.final.x.dtype == jnp.float32 for s in seen)
