"""eki-dip at toy scale: an interrupted search resumed from its checkpoint ends at the same P."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip import checkpoint
from jaxdip import config as C
from jaxdip.runner import get, run_experiment
from float32_jaxpr import float64_equations_of

TINY = {"seeds": 4, "ensemble": 6, "iterations": 6, "chunk": 2, "T": 0.3, "t_star": 0.1, "grad_steps": 0,
        "eval_states": 2, "judge_duration": 0.3, "early_stop": False, "min_success": 2, "variants_table": False}


def _checkpoints(folder) -> list[str]:
    """The checkpoints beside the output folders, without their fingerprint."""
    return sorted(p.name.rsplit(".", 3)[0] for p in folder.glob(".*.ckpt.npz"))


def test_interrupted_search_resumes_to_the_same_P(tmp_path, monkeypatch):
    exp = get("eki-dip")
    cfg = C.load(exp.config_cls, quick=TINY)
    full = run_experiment(exp, cfg, str(tmp_path / "full"))["results"]

    real_save = checkpoint.save
    calls = {"n": 0}

    def save_then_die(*a, **k):
        real_save(*a, **k)
        calls["n"] += 1
        if calls["n"] == 2:  # killed right after the second checkpoint (iteration 4 of 6)
            raise KeyboardInterrupt

    monkeypatch.setattr(checkpoint, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(exp, cfg, str(tmp_path / "resumed"))
    assert not (tmp_path / "resumed").exists()  # nothing half-written
    assert _checkpoints(tmp_path) == [".resumed.eki-dip"]
    monkeypatch.setattr(checkpoint, "save", real_save)
    resumed = run_experiment(exp, cfg, str(tmp_path / "resumed"), resume=True)["results"]
    assert resumed["iterations"] == full["iterations"] == 6
    assert json.dumps(resumed["P_basis"]) == json.dumps(full["P_basis"])
    assert json.dumps(resumed["P_singular_values"]) == json.dumps(full["P_singular_values"])
    assert resumed["history_mean_performance"] == full["history_mean_performance"]
    assert _checkpoints(tmp_path) == []  # removed once the folder is complete


def test_resume_refuses_a_checkpoint_of_another_config(tmp_path, monkeypatch):
    exp = get("eki-dip")
    cfg = C.load(exp.config_cls, quick=TINY)
    real_save = checkpoint.save

    def save_then_die(*a, **k):
        real_save(*a, **k)
        raise KeyboardInterrupt

    monkeypatch.setattr(checkpoint, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(exp, cfg, str(tmp_path / "o"))
    monkeypatch.setattr(checkpoint, "save", real_save)
    other = C.load(exp.config_cls, quick={**TINY, "gamma": 11.0})
    # one line naming the difference, before anything compiles
    with pytest.raises(checkpoint.CheckpointMismatch, match=r"gamma = .* \(this run: 11\.0\)"):
        run_experiment(exp, other, str(tmp_path / "o"), resume=True)


def test_one_free_vector_keeps_its_singular_value_and_per_member_keys_are_wired():
    import experiments.eki_dip as E

    cfg = C.from_dict(E.EkiDipConfig, {"free_vectors": 1, "x0_draw": "per_member", "ensemble": 4, "T": 0.2,
                                            "t_star": 0.1})
    base = jax.random.PRNGKey(0)
    _, _, eki, state, members0, _ = E.build(cfg, base)
    assert members0.V.shape == (4, 1, 6) and eki.member_keys
    np.testing.assert_allclose(np.exp(np.asarray(members0.log_s)), cfg.init_s[0], rtol=1e-12)
    st, _ = eki.step(state)
    m = eki.unravel()(st.members[0])
    np.testing.assert_allclose(float(np.exp(m.log_s[0])), cfg.init_s[0], rtol=1e-12)
    np.testing.assert_allclose(float(jnp.linalg.norm(m.V[0])), 1.0, rtol=1e-12)
    with pytest.raises(C.ConfigError):
        C.from_dict(E.EkiDipConfig, {"free_vectors": 3})


def test_uki_reading_is_wired_and_refuses_resampling():
    import experiments.eki_dip as E

    with pytest.raises(C.ConfigError, match="failure"):
        C.from_dict(E.EkiDipConfig, {"variant": "uki", "failure": "resample"})
    cfg = C.from_dict(E.EkiDipConfig, {"variant": "uki", "schedule": "adaptive", "ensemble": 4, "T": 0.2,
                                       "t_star": 0.1})
    _, _, eki, state, members0, _ = E.build(cfg, jax.random.PRNGKey(0))
    p = int(state.aux["mean"].shape[0])
    # UKI evaluates 2p + 1 sigma points of the Gaussian fitted to the initial ensemble, whatever J is
    assert state.members.shape == (2 * p + 1, p) and eki.kalman().schedule.name == "data_misfit"


def test_variant_table_rows_run_inside_one_run():
    """The variant table at toy scale: a row per reading, the main search's row its own results (not run
    again), the forward evaluations counted per variant (UKI: 2p + 1 sigma points for p = 14 parameters), wall
    times only in ``timing``, and the report's table."""
    import experiments.eki_dip as E

    cfg = C.load(E.EkiDipConfig, quick={**TINY, "T": 0.1, "t_star": 0.05, "iterations": 4, "variants_table": True})
    out = E.run(cfg)
    rows, walls = out.results["variants"], out.timing["variants_wall_s"]
    assert list(rows) == ["eki_fixed", "eki_adaptive_end1", "eki_adaptive_end20", "uki_fixed"] == list(walls)
    main = rows["eki_fixed"]
    assert main["iterations"] == out.results["iterations"] and main["simulations"] == out.results["simulations"]
    assert main["stabilized_fraction"] == out.results["stabilized_fraction"]
    assert main["performance"] == out.results["performance"]["mean"]
    assert walls["eki_fixed"] == out.timing["search_wall_s"]
    sizes = {"eki_fixed": 6, "eki_adaptive_end1": 6, "eki_adaptive_end20": 6, "uki_fixed": 2 * 14 + 1}
    for key, r in rows.items():
        assert r["status"] == "ok" and 1 <= r["iterations"] <= 4, key
        assert r["simulations"] == r["iterations"] * sizes[key], key
        lo, hi = r["stabilized_fraction_ci95"]
        assert lo <= r["stabilized_fraction"] <= hi and np.isfinite(r["performance"]), key
        assert walls[key] > 0
    assert not any("wall" in k for r in rows.values() for k in r)
    table = [line for line in out.report.splitlines() if line.startswith("| ")]
    assert len(table) == 1 + len(rows) and table[1].startswith("| eki fixed (thesis) |")


@pytest.mark.parametrize("iterations, status", [(20, "P_not_finite"), (40, "not_finite")])
def test_a_diverging_reading_is_a_row_that_says_so(iterations, status):
    """UKI with the fixed step inflates its covariance by 1 + dt = 2 every iteration; where the outputs carry no
    information (every sigma point fails) nothing shrinks it. At thesis scale the singular values overflow
    within the 1000 iterations (P not finite: the search ends, its P cannot be judged); later the update
    itself overflows (the search stops). Here both, from a covariance of 1e300: within 20 iterations, and at
    iteration 25 of 40. Either is a row that says so, with the iterations and sigma-point evaluations taken,
    and no judge."""
    import experiments.eki_dip as E

    cfg = C.from_dict(E.EkiDipConfig, {"variant": "uki", "ensemble": 6, "T": 0.02, "t_star": 0.01,
                                       "init_log_s_std": 1e150, "iterations": iterations, "chunk": iterations,
                                       "early_stop": False})

    def evaluate(m):
        raise AssertionError("a search that did not end well is not scored")

    row, wall = E.reading_search(cfg, jax.random.PRNGKey(0), evaluate, "uki_fixed")
    assert row["status"] == status and 1 <= row["iterations"] <= iterations and wall > 0
    assert (row["iterations"] < iterations) == (status == "not_finite")
    assert row["simulations"] == row["iterations"] * (2 * 14 + 1)
    assert row["stabilized_fraction"] is None and row["performance"] is None


def test_float32_forward_model_matches_float64_and_the_update_stays_float64(monkeypatch):
    """search_precision="float32": the members' closed loops run in float32 and their performances come back as
    float64, so the EKI update is float64. A float32 loop draws its x0 and state noise in float32 (other numbers
    than float64's); for common random numbers the test draws every normal in float64 and rounds it. Then, on
    the same members and key, log (2.24) agrees with the float64 forward model to 1e-3 (measured 2.9e-4 over
    0.3 s: float32 rounding, amplified by P's singular values of 1e6 and 1e4 in the control; the search's own
    noise on that scale is R = 1), and differs from it (float32 really ran)."""
    import experiments.eki_dip as E

    normal = jax.random.normal
    monkeypatch.setattr(jax.random, "normal", lambda key, shape=(), dtype=float: normal(key, shape).astype(dtype))
    out = {}
    for p in ("float64", "float32"):
        cfg = C.from_dict(E.EkiDipConfig, {"ensemble": 4, "T": 0.3, "t_star": 0.1, "search_precision": p})
        _, _, eki, state, _, _ = E.build(cfg, jax.random.PRNGKey(0))
        Y = eki.evaluate(state, jax.random.PRNGKey(5))
        new, Y_step = jax.eval_shape(eki.step, state)  # the update's dtypes, traced, not run
        assert Y.dtype == Y_step.dtype == new.members.dtype == jnp.float64, p
        out[p] = np.asarray(Y)
        if p == "float32":  # the closed loop (the scan over periods) has no float64 operation
            member = eki.unravel()(state.members[0])
            eqs = float64_equations_of(lambda m: eki.G(m, jax.random.PRNGKey(5)), member)
            assert eqs and not [e for e in eqs if "/scan" in e], [e for e in eqs if "/scan" in e][:5]
    assert np.all(np.isfinite(out["float64"])) and np.ptp(out["float64"]) > 1.0  # members that differ
    err = np.max(np.abs(out["float32"] - out["float64"]))
    assert 0.0 < err < 1e-3, err
