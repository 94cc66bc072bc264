"""The experiments with a ``precision`` key run their Monte Carlo loops wholly in float32: the jaxpr of each
loop's ``simulate`` (walked into every scan, while, cond and pjit body) has no float64 equation; the key is
validated and recorded in metrics.json's ``dtype``."""

import dataclasses

import jax
import jax.numpy as jnp
import pytest

import jaxdip as jd
from jaxdip import config as C
from jaxdip.runner import get
from jaxdip.runner.experiment import provenance, run_dtype

from float32_jaxpr import float64_equations

WITH_KEY = ("dip-lqr", "dip-controllers", "rwp-remark3", "rwp-bias")


def _cfg(exp_id, **sets):
    exp = get(exp_id)
    return C.load(exp.config_cls, quick={**exp.quick, **sets})


def _float64_in(r: jd.Rollout, steps: int = 4) -> list[str]:
    """float64 equations of the rollout's loop, traced at float32 from a float32 x0 (the Monte Carlo's x0 is
    drawn in float64 and cast by simulate: the draw is not part of the loop)."""
    assert r.loop.precision == "float32"
    x0 = jnp.zeros(r.loop.plant.n, jnp.float32)
    every = r.save_every if r.save is not None else 1

    def run(x0, key):
        return jd.simulate(r.loop, x0, key, steps * every, save=r.save, save_every=every, metrics=r.metrics)

    jaxpr = jax.make_jaxpr(run)(x0, jax.random.key(0))
    assert all(a.dtype != jnp.float64 for a in jax.tree_util.tree_leaves(jaxpr.out_avals))
    return float64_equations(jaxpr.jaxpr)


def test_dip_lqr_loop():
    from experiments import dip_lqr

    assert _float64_in(dip_lqr.build(_cfg("dip-lqr", precision="float32"))) == []


@pytest.mark.parametrize("name", ["lqr", "ps", "rp"])
def test_dip_controllers_loops(name):
    from experiments import dip_controllers as D

    cfg = _cfg("dip-controllers", precision="float32")
    ctrls, _ = D.controllers(cfg, D.plant_of(cfg))
    assert _float64_in(D.build(cfg, ctrls[name])) == []


@pytest.mark.parametrize("name", ["cpx", "ldf"])
def test_dip_cpx_ldf_loops(name):
    """CPX (proximal solve with the power-series controller) and the LDF (its filters discretised in its init,
    in the loop's precision) driving the DIP through encoders, input offset and noise (studied in float32,
    not found safe: no key; the loops still run wholly in float32)."""
    from experiments import dip_cpx_ldf

    assert _float64_in(jd.with_precision(dip_cpx_ldf.build(_cfg("dip-cpx-ldf"))[name], "float32")) == []


def test_rwp_remark3_loop():
    """rwp-remark3's loop (HOMD observer, encoders with bias, state feedback) as the experiment builds it."""
    from jaxdip.estimators import homd
    from jaxdip.plants import rwp as P
    from jaxdip.scenarios import rwp as S

    r = S.rollout(homd.HOMDObserver.build(P.DT, substeps=10), steps=10, theta0=0.1, save_every=1)
    assert _float64_in(jd.with_precision(r, "float32")) == []


def test_lorenz_mhe_loop():
    """The four Lorenz estimators (CPX, sCPX, two EKFs) fanned out on one measurement stream (studied in
    float32, not found safe: no key; the loop still runs wholly in float32)."""
    from experiments import lorenz_mhe

    assert _float64_in(jd.with_precision(lorenz_mhe.build(_cfg("lorenz-mhe"), steps=4), "float32")) == []


def test_rwp_bias_loops(monkeypatch):
    """The first loop of each part of rwp-bias (Luenberger, HOMD, the low-pass bias observers): its Monte Carlo
    call is intercepted, the loop's jaxpr walked, and the part stopped before anything is simulated."""
    cfg = _cfg("rwp-bias", precision="float32")
    seen = {}

    class Seen(Exception):
        pass

    def collect(fn, key, n, **kw):
        name = type(fn.loop.estimator).__name__
        seen[name] = _float64_in(fn)
        raise Seen

    monkeypatch.setattr(jd, "monte_carlo", collect)
    from experiments import rwp_bias

    for part in (rwp_bias.part_a, rwp_bias.part_b, rwp_bias.part_c, rwp_bias.part_d):
        with pytest.raises(Seen):
            part(cfg)
    assert len(seen) >= 3 and all(v == [] for v in seen.values()), seen


@pytest.mark.parametrize("exp_id", WITH_KEY)
def test_precision_key_is_validated_and_recorded(exp_id):
    cfg = _cfg(exp_id)
    assert cfg.precision == "float64" and run_dtype(cfg) == "float64"
    cfg32 = dataclasses.replace(cfg, precision="float32")
    assert run_dtype(cfg32) == "float32 loops, float64 design"
    assert provenance(exp_id, 4, 1.0, cfg=cfg32)["dtype"] == run_dtype(cfg32)  # metrics.json and the report
    with pytest.raises(C.ConfigError, match="precision"):
        _cfg(exp_id, precision="float16")


def test_experiments_without_the_key_refuse_it():
    """The experiments not found safe, or not made float32, have no precision key (docs/performance.md)."""
    for exp_id in ("lorenz-mhe", "dip-cpx-ldf", "twip-dmso", "dip-mpc"):
        with pytest.raises(C.ConfigError, match="unknown key"):
            _cfg(exp_id, precision="float32")
