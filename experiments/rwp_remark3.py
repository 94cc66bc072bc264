"""rwp-remark3: Aranovskiy et al.'s Remark 3, a biased wheel encoder does not bias the wheel-speed estimate.

With the wheel angle measured as theta_r + d_r (d_r constant) and the pendulum angle unbiased, the HOMD (12)'s
error dynamics have the equilibrium e_r,2 = 0. The run: the rwp-bias loop (Table 2 feedback, Table 1
quantisation, 500 Hz) with the HOMD (10)/(12) at the Table 2 gains, from theta(0) = ``theta0``; per seed the
wheel-speed error is the mean of (estimate - truth) over the last ``tail`` seconds, and each wheel bias is
compared with d_r = 0 on the same seeds (paired). A pendulum bias d instead of d_r is the contrast: the same
measure does see a steady-state error there.

A supporting run of the fidelity readings (docs/fidelity/rwp.md): not part of a plain ``jaxdip reproduce``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxdip import config as C
from jaxdip.runner.experiment import Experiment, Outcome, RunContext, precision_field
from jaxdip.runner.per_seed import PerSeed, mean_of
from jaxdip.runner.results import fmt_ci
from jaxdip.resources import Load


@dataclass
class RwpRemark3Config:
    seeds: int = C.field(128, C.positive, doc="noise seeds (the same seeds for every bias: paired)")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    duration: float = C.field(20.0, C.positive_finite, doc="simulated time per seed (s)")
    tail: float = C.field(5.0, C.positive_finite, doc="the error is averaged over the last this many seconds")
    theta0: float = C.field(0.1, C.finite, doc="initial pendulum angle (rad)")
    wheel_biases: list[float] = C.field([0.05, 0.5, 5.0], C.finite, doc="wheel-encoder biases d_r tried (rad)")
    pendulum_bias: float = C.field(0.05, C.finite, doc="contrast: a pendulum bias d (rad) with d_r = 0 (0: none)")
    tolerance: float = C.field(1e-3, C.nonneg_finite, doc="holds when the paired difference's interval contains "
                               "0 or lies within +-tolerance (rad/s)")
    precision: str = precision_field()

    def loads(self) -> list[Load]:
        from jaxdip.plants import rwp as P

        n = int(round(self.duration / P.DT))
        return [Load("the Monte Carlo", ("seeds", "duration"), self.seeds, n, saved=8 * n)]

    def validate(self):
        from jaxdip.plants import rwp as P

        if self.seeds < 2:
            raise C.ConfigError("seeds", "must be at least 2 (the interval comes from their spread)")
        if self.tail > self.duration:
            raise C.ConfigError("tail", f"must not exceed duration ({self.duration} s)")
        if self.tail < P.DT:
            raise C.ConfigError("tail", f"must be at least one period ({P.DT} s)")
        if not self.wheel_biases:
            raise C.ConfigError("wheel_biases", "must list at least one bias")


def compute(cfg: RwpRemark3Config) -> tuple[dict, PerSeed]:
    """The results and their per-seed arrays: per case (the reference, the wheel biases on ``wheel_case``, the
    contrast) each seed's tail-mean error, its result code, the seeds kept and the paired difference."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import jaxdip as jd
    from jaxdip import stats
    from jaxdip.estimators import homd
    from jaxdip.plants import rwp as P
    from jaxdip.scenarios import rwp as S

    steps = int(round(cfg.duration / P.DT))
    est = homd.HOMDObserver.build(P.DT, substeps=10)
    base = jd.with_precision(S.rollout(est, steps=steps, theta0=cfg.theta0, save_every=1), cfg.precision)
    idx = int(round((cfg.duration - cfg.tail) / P.DT))

    def wheel_speed_error(d_r: float, d: float = 0.0):
        r = eqx.tree_at(lambda r: r.loop.sensor.const_bias, base, jnp.array([d, d_r]))
        sol = jd.monte_carlo(r, jax.random.PRNGKey(cfg.seed), cfg.seeds, desc=f"rwp-remark3 d={d:g} d_r={d_r:g}")
        rec = np.asarray(sol.saved)
        err = rec[:, idx:, S.REC["xr2"]] - rec[:, idx:, S.REC["thetar_dot"]]
        return err.mean(1), np.asarray(sol.result)

    e0, r0 = wheel_speed_error(0.0)
    ok0 = r0 == 0
    data = PerSeed()
    err = "mean of (theta_r' estimate - theta_r') over the tail"
    data.add("reference.result", ("seed",), r0, "1", "result code (jaxdip.RESULTS) at d_r = d = 0")
    data.add("reference.ok", ("seed",), ok0, "1", "the seed did not diverge at d_r = d = 0")
    data.add("reference.error", ("seed",), e0, "rad/s", err,
             **mean_of("reference.error_mean", "reference.ok", "reference.error_ci95"))
    m0, ci0 = stats.mean_ci(e0[ok0])
    out = {"theta0": cfg.theta0, "duration_s": cfg.duration, "tail_s": cfg.tail, "tolerance": cfg.tolerance,
           "reference": {"d_r": 0.0, "d": 0.0, "error_mean": m0, "error_ci95": ci0,
                         "diverged": int((~ok0).sum())}}

    def case(d_r, d, name, where):
        e, res = wheel_speed_error(d_r, d)
        ok = (res == 0) & ok0
        dims = ("seed",) if name == "contrast" else ("seed", "wheel_case")
        for var, values, units, text, stat in (
                ("result", res, "1", "result code (jaxdip.RESULTS)", {}),
                ("kept", ok, "1", "the seed diverged neither here nor at d_r = 0", {}),
                ("error", e, "rad/s", err, mean_of(f"{where}.error_mean", f"{name}.kept", f"{where}.error_ci95")),
                ("paired", e - e0, "rad/s", "error minus the same seed's error at d_r = 0",
                 mean_of(f"{where}.paired_mean", f"{name}.kept", f"{where}.paired_ci95"))):
            columns.setdefault(f"{name}.{var}", (dims, [], {"units": units, "long_name": text, **stat}))[1].append(values)
        m, ci = stats.mean_ci(e[ok])
        dm, dci = stats.mean_ci(e[ok] - e0[ok])
        h = ok.any() and ((dci[0] <= 0 <= dci[1]) or (abs(dci[0]) <= cfg.tolerance and abs(dci[1]) <= cfg.tolerance))
        return {"d_r": d_r, "d": d, "error_mean": m, "error_ci95": ci, "paired_mean": dm, "paired_ci95": dci,
                "diverged": int((res != 0).sum()), "kept": int(ok.sum()), "holds": bool(h)}

    columns = {}  # the per-seed variables of the cases, one column per wheel bias
    out["wheel"] = [case(d_r, 0.0, "wheel", "wheel.{wheel_case}") for d_r in cfg.wheel_biases]
    if cfg.pendulum_bias != 0:
        out["contrast"] = case(0.0, cfg.pendulum_bias, "contrast", "contrast")
    for name, (dims, values, attrs) in columns.items():
        data.variables[name] = (dims, np.stack(values, axis=1) if len(dims) == 2 else values[0], attrs)
    data.coords["wheel_case"] = np.arange(len(cfg.wheel_biases))
    data.coords["wheel_bias"] = ("wheel_case", list(cfg.wheel_biases))
    rows = [out["reference"], *out["wheel"], *([out["contrast"]] if "contrast" in out else [])]
    if any(c["diverged"] for c in rows):  # a seed diverged in a row: its pairs are left out of every comparison
        out["failures"] = {"diverged": {f"d_r={c['d_r']:g}, d={c['d']:g}": c["diverged"] for c in rows},
                           "of_seeds": cfg.seeds}
    return out, data


def _ci(v, ci) -> str:
    return fmt_ci(v, ci, 3, missing="n/a (no seed kept)")


def report(cfg: RwpRemark3Config, r: dict) -> str:
    L = [f"Remark 3: with the wheel angle measured with a constant bias d_r and the pendulum angle unbiased, the "
         f"HOMD (12)'s error dynamics have the equilibrium e_r,2 = 0: no steady-state bias of the wheel-speed "
         f"estimate. Ours: the rwp-bias loop with the HOMD (10)/(12) at the Table 2 gains, theta(0) = "
         f"{cfg.theta0:g} rad, {cfg.seeds} seeds of {cfg.duration:g} s; the wheel encoder reads theta_r + d_r. "
         f"Error = mean of (theta_r' estimate - theta_r') over the last {cfg.tail:g} s, paired with the same seeds "
         f"at d_r = 0 (95% intervals over seeds). Holds when the paired difference's interval contains 0 or lies "
         f"within +-{cfg.tolerance:g} rad/s. The contrast row (a pendulum bias d instead) shows that the measure "
         "detects a steady-state error where there is one.", "",
         "| wheel bias d_r (rad) | pendulum bias d (rad) | wheel-speed error (rad/s) | paired minus d_r = 0 | "
         "diverged | holds |", "|---|---|---|---|---|---|"]
    ref = r["reference"]
    L.append(f"| 0 | 0 | {_ci(ref['error_mean'], ref['error_ci95'])} | — | {ref['diverged']} | — |")
    for c in r["wheel"] + ([r["contrast"]] if "contrast" in r else []):
        h = ("yes" if c["holds"] else "no") if c["kept"] else "n/a"
        L.append(f"| {c['d_r']:g} | {c['d']:g} | {_ci(c['error_mean'], c['error_ci95'])} | "
                 f"{_ci(c['paired_mean'], c['paired_ci95'])} | {c['diverged']} | "
                 f"{h if c['d'] == 0 else '(contrast) ' + h} |")
    if "failures" in r:
        L += ["", f"Diverged seeds (of {r['failures']['of_seeds']}): "
              + ", ".join(f"{k}: {v}" for k, v in r["failures"]["diverged"].items())
              + "; a row keeps the seeds that diverged neither there nor at d_r = 0 (n/a: none kept)."]
    return "\n".join(L)


def run(cfg: RwpRemark3Config, ctx: RunContext | None = None) -> Outcome:
    r, data = compute(cfg)
    return Outcome(results=r, report=report(cfg, r), per_seed=data)


EXPERIMENT = Experiment(
    id="rwp-remark3",
    title="reaction-wheel pendulum: a biased wheel encoder and the wheel-speed estimate (fidelity readings)",
    config_cls=RwpRemark3Config,
    run=run,
    quick={"seeds": 16, "duration": 6.0, "tail": 2.0},
    source="Aranovskiy et al., Remark 3 (§III-C)",
    reproduce=False,
)
