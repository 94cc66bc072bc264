"""jaxdip.tune: transforms, the tuner (quadratic convergence, checkpoint/resume), and the gradients of every
target (cpx, rwp, dmso, rp, extra) against central finite differences."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip import config as C
import experiments.tune.config as T
from jaxdip.scenarios import heldout as H
from jaxdip.scenarios import tune_targets as TT
from jaxdip.tune import (Bounded, Log, Softplus, SPDFactor, Unconstrained, random_search, to_constrained,
                         to_unconstrained, tune, value_and_grad_fn)


class _Draw(eqx.Module):
    """A trial whose output is its key's first normal draw times a hyperparameter."""

    scale: jax.Array

    def __call__(self, key):
        return self.scale * jax.random.normal(key)


def test_mc_objective_runs_seed_i_with_fold_in_of_the_key():
    """mc_objective at scattered seed indices: seed i's loss is the trial run alone with fold_in(key, i), in the
    order given (one monte_carlo call per contiguous run), its mean the objective, its gradient the analytic one."""
    from jaxdip.tune import mc_objective, seed_runs

    seeds = [0, 1, 2, 7, 1_000_000, 1_000_001]
    assert seed_runs(seeds) == [(0, 3), (7, 1), (1_000_000, 2)]
    key = jax.random.PRNGKey(11)
    obj = mc_objective(lambda th: _Draw(th["s"]), seeds, lambda y: y**2)
    ref = np.array([float(jax.random.normal(jax.random.fold_in(key, i))) ** 2 for i in seeds])
    got = np.asarray(obj.per_seed({"s": jnp.asarray(1.0)}, key))
    np.testing.assert_allclose(got, ref, rtol=1e-14)
    np.testing.assert_allclose(float(obj({"s": jnp.asarray(2.0)}, key)), 4.0 * ref.mean(), rtol=1e-13)
    g = jax.grad(lambda s: obj({"s": s}, key))(jnp.asarray(2.0))  # d/ds mean (s y)^2 = 2 s mean y^2
    np.testing.assert_allclose(float(g), 4.0 * ref.mean(), rtol=1e-12)


def test_transforms_round_trip():
    theta = {"a": jnp.asarray(3.0), "b": jnp.asarray([0.2, 5.0]), "c": jnp.asarray(0.3),
             "P": jnp.asarray([[2.0, 0.5], [0.5, 1.0]]), "d": jnp.asarray([-1.5, 0.0])}
    spec = {"a": Log(), "b": Softplus(), "c": Bounded(0.0, 1.0), "P": SPDFactor(), "d": Unconstrained()}
    back = to_constrained(spec, to_unconstrained(spec, theta))
    for k in theta:
        np.testing.assert_allclose(back[k], theta[k], rtol=1e-12)
    # any unconstrained value maps into the constraint set
    u = jax.tree_util.tree_map(lambda x: -50.0 * jnp.ones_like(x), to_unconstrained(spec, theta))
    th = to_constrained(spec, u)
    assert th["a"] > 0 and jnp.all(th["b"] > 0) and 0 <= th["c"] < 1
    P = SPDFactor().forward(jnp.asarray([[0.0, 0.0], [9.0, -3.0]]))
    assert jnp.all(jnp.linalg.eigvalsh(P) > 0)


def quadratic(theta, key):
    # minimum at a = 2, b = [0.5, 3]; key-dependent noise-free (CRN irrelevant)
    return (jnp.log(theta["a"]) - jnp.log(2.0)) ** 2 + jnp.sum((theta["b"] - jnp.asarray([0.5, 3.0])) ** 2)


def test_tuner_converges_on_quadratic():
    init = {"a": jnp.asarray(10.0), "b": jnp.asarray([2.0, 0.1])}
    res = tune(quadratic, init, jax.random.PRNGKey(0), steps=300, lr=0.05, spec={"a": Log(), "b": Softplus()},
               progress=False)
    np.testing.assert_allclose(res.theta["a"], 2.0, rtol=1e-3)
    np.testing.assert_allclose(res.theta["b"], [0.5, 3.0], atol=1e-3)
    assert res.loss_history[-1] < 1e-5 < res.loss_history[0]
    assert res.theta_history["b"].shape == (300, 2)


def test_rprop_grows_its_step_along_a_one_sided_slope():
    """The cpx situation: J falls monotonically in log gamma towards a far edge. Rprop's step after k steps of a
    constant-sign gradient is lr * 1.2**k; Adam's is at most about lr (why the cpx run uses rprop)."""
    import optax

    J = lambda th, key: -jnp.tanh(0.1 * jnp.log(th["g"]))  # noqa: E731  slope of one sign, shrinking
    init = {"g": jnp.asarray(150.0)}
    res = tune(J, init, jax.random.PRNGKey(0), steps=12, lr=0.3, spec={"g": Log()}, optimizer=optax.rprop(0.3),
               progress=False)
    steps = np.diff(np.log(np.asarray(res.theta_history["g"])))
    # optax's Rprop makes a zero first move (no previous sign), then lr, lr * 1.2, lr * 1.2**2, ...
    np.testing.assert_allclose(steps, [0.0] + [0.3 * 1.2 ** j for j in range(10)], rtol=1e-9, atol=1e-12)
    moved = float(np.log(res.theta_history["g"][-1] / 150.0))
    adam = tune(J, init, jax.random.PRNGKey(0), steps=12, lr=0.3, spec={"g": Log()}, clip=None, progress=False)
    assert np.log(float(adam.theta_history["g"][-1]) / 150.0) <= 0.3 * 11 + 1e-9 < moved
    assert C.load(T.TuneConfig, sets=["optimizer=rprop"]).optimizer == "rprop"
    with pytest.raises(C.ConfigError, match="one of"):
        C.load(T.TuneConfig, sets=["optimizer=sgd"])


def test_early_stopping():
    res = tune(lambda th, k: jnp.asarray(1.0) + 0.0 * th["a"], {"a": jnp.asarray(1.0)}, jax.random.PRNGKey(0),
               steps=50, early_stop_patience=3, progress=False)
    assert res.stopped_early and res.steps == 4


@pytest.mark.parametrize("mode", ["forward", "reverse"])
def test_checkpoint_resume_gives_identical_trajectory(tmp_path, mode):
    init = {"a": jnp.asarray(10.0), "b": jnp.asarray([2.0, 0.1])}
    noisy = lambda th, k: quadratic(th, k) * (1.0 + 0.1 * jax.random.normal(k))  # resampled keys: key matters
    kw = dict(steps=12, lr=0.1, spec={"a": Log(), "b": Softplus()}, common_random_numbers=False, progress=False,
              mode=mode)
    full = tune(noisy, init, jax.random.PRNGKey(3), **kw)
    path = str(tmp_path / "ck.npz")

    def boom(step, theta, loss):
        if step == 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        tune(noisy, init, jax.random.PRNGKey(3), checkpoint_path=path, callback=boom, **kw)
    resumed = tune(noisy, init, jax.random.PRNGKey(3), checkpoint_path=path, resume=True, **kw)
    np.testing.assert_array_equal(resumed.loss_history, full.loss_history)
    np.testing.assert_array_equal(resumed.theta_history["b"], full.theta_history["b"])
    np.testing.assert_array_equal(resumed.theta["a"], full.theta["a"])
    # a different run refuses the checkpoint
    with pytest.raises(ValueError):
        tune(noisy, init, jax.random.PRNGKey(3), checkpoint_path=path, resume=True, fingerprint="other", **kw)


def test_random_search_finds_best_sample():
    res = random_search(lambda th: (th - 0.3) ** 2, lambda k: jax.random.uniform(k), 64, jax.random.PRNGKey(1),
                        progress=False)
    assert res.loss == res.losses.min() and abs(float(res.theta) - 0.3) < 0.05


def test_unknown_target_is_a_config_error():
    with pytest.raises(C.ConfigError, match="must be one of") as e:
        C.load(T.TuneConfig, sets=["target=nonsense"])
    assert e.value.key == "target"
    for t in T.IMPLEMENTED:
        assert C.load(T.TuneConfig, sets=[f"target={t}"]).target == t


def _tiny_cpx(quanta):
    cfg = C.load(T.TuneConfig, sets=["duration=0.06", "substeps=2"])
    return TT.make_target(cfg, quanta=quanta)


def test_cpx_gradient_matches_central_differences():
    """Without quantisation the loss is smooth in gamma: forward-mode derivative = central FD (rel 1e-4)."""
    tg = _tiny_cpx([0.0, 0.0, 0.0])
    J = tg.objective(np.arange(3), smooth=False)
    key = jax.random.PRNGKey(0)
    f = lambda lg: J({"gamma": jnp.exp(lg)}, key)
    lg0 = jnp.log(150.0)
    vg = jax.jit(value_and_grad_fn(f))  # its value output gives the differences too: one compilation
    val, g = vg(lg0)
    h = 1e-4
    fd = (vg(lg0 + h)[0] - vg(lg0 - h)[0]) / (2 * h)
    assert abs(float(g)) > 1e-8
    np.testing.assert_allclose(float(g), float(fd), rtol=1e-4)
    assert np.isfinite(float(val))


@pytest.mark.slow
def test_reverse_mode_through_the_cpx_target_matches_forward():
    """mode = reverse: jax.grad through monte_carlo's compiled batch equals the forward-mode derivative."""
    tg = _tiny_cpx([0.0, 0.0, 0.0])
    J = tg.objective(np.arange(2), smooth=False)
    key = jax.random.PRNGKey(0)
    f = lambda lg: J({"gamma": jnp.exp(lg)}, key)
    lg0 = jnp.log(150.0)
    g_rev = jax.jit(jax.grad(f))(lg0)
    val, g_fwd = jax.jit(value_and_grad_fn(f))(lg0)
    assert abs(float(g_fwd)) > 1e-8
    np.testing.assert_allclose(float(g_rev), float(g_fwd), rtol=1e-8)
    np.testing.assert_allclose(float(jax.jit(f)(lg0)), float(val), rtol=1e-13)


@pytest.mark.slow
def test_reverse_mode_with_checkpointed_chunks_matches_forward():
    """checkpointed() on the DIP under power-series control fed by CPX (the dip-cpx-ldf scenario, exact
    encoders off): reverse mode through checkpointed chunks equals forward mode through one scan, and chunking
    changes no value."""
    from jaxdip.scenarios import dip_cpx_ldf as S
    from jaxdip.tune import checkpointed

    sc = S.DipCpxLdf(duration=0.06, substeps=2, encoder_quanta=(0.0, 0.0, 0.0))
    base = sc.rollout("cpx")
    key = jax.random.PRNGKey(0)

    def f(lg, chunk):
        var = checkpointed(S.with_gamma(base, jnp.exp(lg)), key, chunk).metrics["x"]["var"]
        return var[1] + var[2]

    lg0 = jnp.log(150.0)
    g_rev = jax.jit(jax.grad(lambda lg: f(lg, 7)))(lg0)
    g_fwd = jax.jit(value_and_grad_fn(lambda lg: f(lg, 0)))(lg0)[1]
    assert abs(float(g_fwd)) > 0
    np.testing.assert_allclose(float(g_rev), float(g_fwd), rtol=1e-8)
    np.testing.assert_allclose(float(f(lg0, 7)), float(f(lg0, 0)), rtol=1e-13)


def test_rwp_gradient_matches_central_differences():
    """k_p1, k_p2, alpha_p, L0 through their transforms; unquantised encoders make the loss smooth."""
    cfg = C.load(T.TuneConfig, sets=["target=rwp", "duration=0.2", "substeps=2"])
    tg = TT.make_target(cfg, quantize=False)
    J = tg.objective(np.arange(2), smooth=False)
    key = jax.random.PRNGKey(0)
    u0 = to_unconstrained(tg.spec, tg.paper)
    f = lambda u: J(to_constrained(tg.spec, u), key)
    vg = jax.jit(value_and_grad_fn(f))
    fj = lambda u: vg(u)[0]
    _, g = vg(u0)
    h = 1e-5
    for k in u0:
        up, um = dict(u0), dict(u0)
        up[k], um[k] = u0[k] + h, u0[k] - h
        fd = (fj(up) - fj(um)) / (2 * h)
        assert abs(float(g[k])) > 1e-6
        np.testing.assert_allclose(float(g[k]), float(fd), rtol=1e-4, err_msg=k)


def _check_fd(tg, J, h=1e-5):
    key = jax.random.PRNGKey(0)
    u0 = to_unconstrained(tg.spec, tg.paper)
    vg = jax.jit(value_and_grad_fn(lambda u: J(to_constrained(tg.spec, u), key)))
    _, g = vg(u0)
    for k in u0:
        for j in np.ndindex(np.shape(u0[k])):
            e = jnp.zeros_like(u0[k]).at[j].set(h)
            up, um = dict(u0), dict(u0)
            up[k], um[k] = u0[k] + e, u0[k] - e
            fd = (vg(up)[0] - vg(um)[0]) / (2 * h)
            assert abs(float(g[k][j])) > 1e-6
            np.testing.assert_allclose(float(g[k][j]), float(fd), rtol=1e-4, err_msg=f"{k}{j}")


def test_dmso_gradient_matches_central_differences():
    """Gamma and diag K_MSO through log, noisy TWIP case (sensor noise on, encoder quantum 0: smooth)."""
    cfg = C.load(T.TuneConfig, sets=["target=dmso", "duration=0.2"])
    tg = TT.make_target(cfg, quantum=0.0)
    _check_fd(tg, tg.objective(np.arange(2), smooth=False))


def test_rp_gradient_matches_central_differences():
    """gamma of (2.14) through log, DIP with the fixed LQR-derived P; log (2.24) (no seed fails here)."""
    cfg = C.load(T.TuneConfig, sets=["target=rp", "duration=0.3"])
    tg = TT.make_target(cfg)
    _check_fd(tg, tg.objective(np.arange(2), smooth=False))


def test_extra_gradient_matches_central_differences():
    """k1, k2 and the four learning rates through log, unmodeled TWIP case, Table 8.3's score (2 seeds, 1 s,
    2 sub-steps: no seed falls, so the score is smooth; measured agreement 1e-8 to 1e-6). The networks adapt
    from zero weights, so over a shorter horizon the learning rates' derivatives drop towards 1e-6 of J's scale
    and central differences lose their digits to rounding; h = 1e-3 is where both errors are small."""
    cfg = C.load(T.TuneConfig, sets=["target=extra", "duration=1.0", "substeps=2"])
    tg = TT.make_target(cfg)
    J = tg.objective(np.arange(2), smooth=False)
    assert not np.any(np.asarray(J.diverged(tg.paper, jax.random.PRNGKey(0))))
    _check_fd(tg, J, h=1e-3)


def test_extra_seeds_are_the_studys_seeds():
    """Seed i of the target is seed i of the twip-extra-control study (same V1, V2, x0; seed 0 at (184)): the
    per-seed loss at the documents' values is that study's score, each seed run alone (no seed diverges)."""
    import jaxdip as jd
    from jaxdip.scenarios import twip_extra as S
    from jaxdip.scenarios.twip_initial import thesis_x0

    cfg = C.load(T.TuneConfig, sets=["target=extra", "duration=0.3", "substeps=2"])
    tg = TT.make_target(cfg)
    seeds = np.asarray([0, 1, T.HELDOUT_OFFSET])
    mine = np.asarray(tg.objective(seeds, smooth=False).per_seed(tg.paper, jax.random.PRNGKey(0)))
    lp = S.loop("unmodeled", "extra", S.controller(), substeps=2)
    ref = []
    for i in seeds:
        s, d, _ = jd.monte_carlo(S.scored(lp, thesis_x0(), 0.0 if i == 0 else 0.1, 30), jax.random.PRNGKey(0), 1,
                                 offset=int(i))
        assert not bool(d[0])
        ref.append(float(s[0]))
    np.testing.assert_allclose(mine, ref, rtol=1e-12)
    assert len(set(np.round(mine, 9))) == 3  # the seeds differ


def _cli(tmp_path, *args):
    import json
    import os
    import subprocess
    import sys

    out = tmp_path / "o"
    r = subprocess.run([sys.executable, "-m", "jaxdip.cli", "run", "tune", *args, "--out", str(out)],
                       capture_output=True, text=True, env=dict(os.environ, JAXDIP_NO_PROGRESS="1"), timeout=600)
    assert r.returncode == 0, r.stderr
    return json.loads((out / "metrics.json").read_text())["results"], out


@pytest.mark.slow
def test_extra_tiny_cli_run(tmp_path):
    """target=extra end to end through the CLI at a tiny scale (2 tuning seeds, 4 held-out, 0.2 s; 20 s)."""
    sets = ["target=extra", "seeds=2", "heldout_seeds=4", "duration=0.2", "steps=2", "landscape_points=3",
            "substeps=2"]
    res, out = _cli(tmp_path, *[a for s in sets for a in ("--set", s)])
    r = res["extra"]
    assert set(r["tuned_value"]) == set(TT.ExtraTarget.KEYS)
    assert r["paper_value"] == {"k1": 2.5, "k2": 2.5, "gamma11": 0.1, "gamma12": 0.1, "gamma21": 0.1,
                                "gamma22": 0.1}
    assert r["simulations_used"] == r["random_search_simulations"] == 4
    assert r["heldout_diverged_paper"] == 0
    assert r["loss_tuned_ci95"][0] <= r["loss_tuned"] <= r["loss_tuned_ci95"][1]
    assert (out / "tune_extra.png").is_file() and "Held-out seeds diverged" in (out / "report.md").read_text()


@pytest.mark.slow
def test_extra_quick_cli_under_a_minute(tmp_path):
    import time

    t0 = time.perf_counter()
    res, _ = _cli(tmp_path, "--quick", "--set", "target=extra")
    assert time.perf_counter() - t0 < 60 and np.isfinite(res["extra"]["loss_tuned"])


class _Probe(eqx.Module):
    """A trial that returns its scaled leaf and a draw from its own key (to see both streams)."""

    a: jax.Array

    def __call__(self, key):
        return self.a, jax.random.normal(key)


def test_scenario_draw_is_uniform_per_entry_and_keeps_the_trials_noise():
    from scipy import stats as sps

    import jaxdip as jd

    a, s, n = jnp.array([2.0, -0.5]), 0.4, 4000
    plain = jd.monte_carlo(_Probe(a), jax.random.PRNGKey(3), n)
    drawn = jd.monte_carlo(H.with_scenarios(_Probe(a), {"x0": [lambda p: p.a]}, {"x0": s}),
                           jax.random.PRNGKey(3), n)
    np.testing.assert_array_equal(np.asarray(plain[1]), np.asarray(drawn[1]))  # the trial's noise unchanged
    f = np.asarray(drawn[0]) / np.asarray(a)
    for j in range(2):  # factor 1 + U(-s, s), each entry on its own
        assert sps.kstest(f[:, j], sps.uniform(loc=1 - s, scale=2 * s).cdf).pvalue > 1e-3
    assert abs(np.corrcoef(f[:, 0], f[:, 1])[0, 1]) < 0.1
    # a spread of 0 (or a kind the trial lacks) leaves the trial itself
    p = _Probe(a)
    assert H.with_scenarios(p, {"x0": [lambda q: q.a]}, {"x0": 0.0, "bias": 0.3}) is p


def test_heldout_spreads_are_validated():
    with pytest.raises(C.ConfigError) as e:
        C.load(T.TuneConfig, sets=["heldout_bias_spread=1.0"])
    assert e.value.key == "heldout_bias_spread"


@pytest.mark.parametrize("target", ["rwp", "rp"])
def test_heldout_scenarios_change_each_seed_and_spread_zero_is_the_tuning_scenario(target):
    cfg = C.load(T.TuneConfig, sets=[f"target={target}", "duration=0.2", "substeps=2"])
    tg = TT.make_target(cfg, **({"quantize": False} if target == "rwp" else {}))
    key, seeds = jax.random.PRNGKey(0), np.arange(4)
    nominal = np.asarray(tg.objective(seeds, smooth=False).per_seed(tg.paper, key))
    zero = {k: 0.0 for k in H.SCENARIO_KINDS}
    same = np.asarray(tg.objective(seeds, smooth=False, scenarios=zero).per_seed(tg.paper, key))
    np.testing.assert_array_equal(nominal, same)
    varied = np.asarray(tg.objective(seeds, smooth=False, scenarios=cfg.scenario_spreads()).per_seed(tg.paper, key))
    assert np.all(np.isfinite(varied)) and np.all(np.abs(varied - nominal) > 1e-6 * np.abs(nominal))


@pytest.mark.parametrize("target", sorted(TT.TARGETS))
def test_paper_values_are_strong_float64(target):
    """A weak-typed value (``jnp.asarray`` of a Python float) keys another program than the tuned value's array
    of the same shape: the held-out evaluation of the paper's value compiled a program of its own."""
    tg = TT.make_target(C.load(T.TuneConfig, sets=[f"target={target}", "duration=0.2", "substeps=2"]))
    for leaf in jax.tree_util.tree_leaves(tg.paper):
        assert isinstance(leaf, jax.Array) and leaf.dtype == jnp.float64 and not leaf.weak_type
