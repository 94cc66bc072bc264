"""dip-mpc: constrained linear MPC against LQR with saturation and relaxed projection control with saturation on
the printed DIP with a motor-voltage limit, from the eki-dip study's random initial states scaled up until the
limit binds; and the MPC's weights tuned by gradient (``jaxdip.tune``, implicit QP gradients through the closed
loop) beside the LQR's. An extension beyond the documents (they give no MPC and no voltage limit for the DIP);
the scenario is ``jaxdip.scenarios.dip_mpc``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip import config as C
from jaxdip import stats
from jaxdip.plants import dip
from jaxdip.resources import Load, steps_of
from jaxdip.runner.experiment import Experiment, Outcome, RunContext
from jaxdip.runner.per_seed import PATHS, PerSeed, fraction_of, mean_of, stacked
from jaxdip.runner.results import fmt_ci
from jaxdip.runner.summaries import loop_summary
from jaxdip.scenarios import dip_mpc as S
from jaxdip.tune import Log, tune

NAMES = ("mpc", "mpc_tuned", "lqr_sat", "rp_sat")


@dataclass
class DipMpcConfig:
    seeds: int = C.field(1000, C.positive, doc="Monte Carlo seeds per controller and initial-state scale")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    duration: float = C.field(2.5, C.positive_finite, doc="simulated time (s)")
    dt: float = C.field(0.01, C.positive_finite, doc="control period (s)")
    u_max: float = C.field(6.0, C.positive_finite, doc="motor voltage limit (V)")
    track: float = C.field(0.4, C.positive_finite, doc="cart track limit |xc| (m): violations counted")
    track_in_mpc: bool = C.field(False, doc="the track also as the MPC's soft state limit (three times the QP "
                                            "rows: about ten times the CPU time)")
    horizon: int = C.field(20, C.positive, doc="MPC horizon (periods)")
    x0_scales: list[float] = C.field([1.0, 4.0, 8.0], C.nonneg_finite,
                                     doc="initial states: eki-dip's N(0, diag(0.01, 0.01, 0.01, 0, 0, 0)^2) std times "
                                         "each of these")
    tune_steps: int = C.field(10, C.positive, doc="gradient steps tuning the MPC weights")
    tune_seeds: int = C.field(16, C.positive, doc="seeds of the tuning objective (common random numbers)")
    tune_scale: float = C.field(2.0, C.positive_finite, doc="initial-state scale the weights are tuned at")
    tune_lr: float = C.field(0.02, C.positive_finite, doc="Adam's step on the log-weights")
    qp_max_iter: int = C.field(40, C.positive, doc="MPC: active-set iterations per period (warm-started)")
    tune_duration: float = C.field(2.0, C.positive_finite, doc="simulated time of the tuning objective (s)")

    def loads(self) -> list[Load]:
        n = steps_of(self.duration, self.dt)
        return [Load("the Monte Carlo", ("seeds", "duration", "x0_scales"), self.seeds * len(self.x0_scales) * 4, n)]

    def setup(self) -> S.Setup:
        return S.Setup(dt=self.dt, duration=self.duration, u_max=self.u_max, track=self.track, track_in_mpc=self.track_in_mpc, horizon=self.horizon,
                       qp_max_iter=self.qp_max_iter)


def tune_weights(cfg: DipMpcConfig, progress: bool):
    """The MPC's Q (xc, alpha, theta) and R tuned by Adam on the mean closed-loop cost over ``tune_seeds``."""
    s = cfg.setup()
    steps = steps_of(cfg.tune_duration, cfg.dt)
    theta0 = {"q": jnp.asarray(s.Q[:3]), "r": jnp.asarray(s.R)}

    def J(theta, key):
        r = S.rollout(s, S.tuned_mpc(s, theta), x0_scale=cfg.tune_scale, steps=steps)
        return jnp.mean(jd.monte_carlo(r, key, cfg.tune_seeds).metrics["cost"])

    res = tune(J, theta0, jax.random.PRNGKey(cfg.seed + 1), steps=cfg.tune_steps, lr=cfg.tune_lr,
               spec={"q": Log(), "r": Log()}, progress=progress, desc="dip-mpc tune")
    return res, float(res.loss_history[0])


def run(cfg: DipMpcConfig, ctx: RunContext | None = None, progress: bool = True) -> Outcome:
    import matplotlib.pyplot as plt

    s = cfg.setup()
    res, J0 = tune_weights(cfg, progress)
    ctrls = S.controllers(s)
    ctrls["mpc_tuned"] = (S.tuned_mpc(s, res.theta), jd.Identity())
    key = jax.random.PRNGKey(cfg.seed)
    scales = jnp.asarray(cfg.x0_scales)
    results = {"table": {}, "tuning": {}, "paired": {}}
    stab, parts = {}, {}
    for name in NAMES:
        ctrl, act = ctrls[name]
        r = S.rollout(s, ctrl, act)
        std0 = r.x0.std
        # the MPC's batch is not sharded over host devices: with two, a full-scale run hung (no CPU, threads in
        # futex waits) in its first chunk, likely the shards' vmapped QP while_loops running different trip
        # counts around a collective; on one device it runs
        sols = jd.monte_carlo(r, key, cfg.seeds, progress=progress, desc=f"dip-mpc {name}",
                              sweep=(lambda ro: ro.x0.std, scales[:, None] * std0[None, :]),
                              shard=False if name.startswith("mpc") else None)
        for j, sc in enumerate(cfg.x0_scales):
            sol = jax.tree_util.tree_map(lambda a: a[j], sols)
            summ = loop_summary(sol, dip.STATE_NAMES, (1, 2), s.stabilized_tol, dt=s.dt, bound=s.state_bound)
            ok = np.asarray(sol.result) == jd.RESULTS.ok
            over = int(np.sum(np.asarray(sol.metrics["max_x"])[:, 0] > s.track))
            frac, ci = stats.wilson(over, cfg.seeds)
            row = {"stabilized_fraction": summ["stabilized_fraction"],
                   "stabilized_fraction_ci95": summ["stabilized_fraction_ci95"], "diverged": summ["diverged"],
                   "track_violation_fraction": frac, "track_violation_fraction_ci95": ci}
            if "failures" in summ:  # how the seeds that failed did (out of bounds, non-finite), and when
                row["failures"] = summ["failures"]
            if ok.any():
                row["mean_abs_u"], row["mean_abs_u_ci95"] = stats.mean_ci(
                    np.asarray(sol.metrics["u"]["mean_abs"])[:, 0], ok)
                row["cost"], row["cost_ci95"] = stats.mean_ci(np.asarray(sol.metrics["cost"]), ok)
            if "qp_unsolved" in sol.metrics:
                row["qp_unsolved_periods"] = int(np.sum(np.asarray(sol.metrics["qp_unsolved"])))
                row["qp_max_iterations"] = int(np.max(np.asarray(sol.metrics["qp_iterations"])))
            results["table"].setdefault(f"x{sc:g}", {})[name] = row
            # per seed, for the paired comparison (every controller starts from the same states)
            stab[(f"x{sc:g}", name)] = ok & np.all(np.asarray(sol.metrics["tail"])[:, 1:3] < s.stabilized_tol, axis=1)
            parts.setdefault(f"x{sc:g}", {})[name] = seed_part(s, sol, ok, stab[(f"x{sc:g}", name)])
    for sc in (f"x{v:g}" for v in cfg.x0_scales):
        for name in NAMES[1:]:
            d = stab[(sc, "mpc")].astype(float) - stab[(sc, name)].astype(float)
            diff, ci = stats.mean_ci(d)
            results["paired"].setdefault(sc, {})[f"mpc_minus_{name}"] = {"stabilized_fraction": diff,
                                                                         "stabilized_fraction_ci95": ci}
    results["tuning"] = {"lqr_weights": {"q": list(s.Q[:3]), "r": s.R},
                         "tuned_weights": {"q": np.asarray(res.theta["q"]).tolist(), "r": float(res.theta["r"])},
                         "cost_before": J0, "cost_after": float(res.loss), "steps": int(res.steps)}

    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.8 / len(NAMES)
    for i, name in enumerate(NAMES):
        fr = [results["table"][f"x{sc:g}"][name]["stabilized_fraction"] for sc in cfg.x0_scales]
        lo_hi = np.array([results["table"][f"x{sc:g}"][name]["stabilized_fraction_ci95"] for sc in cfg.x0_scales])
        xs = np.arange(len(cfg.x0_scales)) + i * width
        ax.bar(xs, fr, width, label=name, yerr=[np.array(fr) - lo_hi[:, 0], lo_hi[:, 1] - np.array(fr)], capsize=2)
    ax.set_xticks(np.arange(len(cfg.x0_scales)) + 0.4 - width / 2, [f"x{sc:g}" for sc in cfg.x0_scales])
    ax.set_xlabel("initial-state std (times eki-dip's)")
    ax.set_ylabel("stabilised fraction (95% CI)")
    ax.set_title(f"DIP, |u| <= {cfg.u_max:g} V, {cfg.seeds} seeds")
    ax.legend(fontsize=8)
    return Outcome(results=results, report=report(cfg, results), figures={"stabilized": fig},
                   per_seed=table_part(parts))


def seed_part(s, sol, ok, stabilized) -> PerSeed:
    """One table cell's per-seed arrays, each labelled with the statistic of its row."""
    part = PerSeed()
    part.add("ok", ("seed",), ok, "1", "the run ended without a failure (the engine's result code is ok)")
    part.add("stabilized", ("seed",), stabilized, "1", "ok, and max |alpha|, |beta| over the tail window below "
             f"{s.stabilized_tol}", **fraction_of("stabilized_fraction"))
    part.add("track_violation", ("seed",), np.asarray(sol.metrics["max_x"])[:, 0] > s.track, "1",
             f"the cart left the track (|xc| > {s.track} m)", **fraction_of("track_violation_fraction"))
    part.add("mean_abs_u", ("seed",), np.asarray(sol.metrics["u"]["mean_abs"])[:, 0], "V", "time mean of |u|",
             **mean_of("mean_abs_u"))
    part.add("cost", ("seed",), np.asarray(sol.metrics["cost"]), "1", "quadratic cost over the periods before a "
             "failure", **mean_of("cost"))
    return part


def table_part(parts: dict) -> PerSeed:
    """The cells stacked on (seed, x0_scale, controller), their statistics under ``results["table"]``."""
    out = stacked({sc: stacked(cells, "controller") for sc, cells in parts.items()}, "x0_scale")
    for _, _, attrs in out.variables.values():
        attrs.update({k: f"table.{attrs[k]}" for k in PATHS if attrs.get(k)})
    return out


def _winner(row: dict) -> str:
    best = max(row.values(), key=lambda r: r["stabilized_fraction"])
    tops = [n for n, r in row.items() if r["stabilized_fraction_ci95"][1] >= best["stabilized_fraction_ci95"][0]]
    return tops[0] if len(tops) == 1 else "tie: " + ", ".join(tops)


def report(cfg: DipMpcConfig, r: dict) -> str:
    lines = [
        "An extension beyond the documents: they give neither an MPC nor a voltage limit for the DIP.",
        "",
        f"Printed DIP, control period {cfg.dt} s, motor limit |u| <= {cfg.u_max} V, track |xc| <= {cfg.track} m "
        f"({'soft in the MPC, ' if cfg.track_in_mpc else 'not in the MPC, '}counted as a violation for all), noise-free full-state feedback, {cfg.duration} s, "
        f"{cfg.seeds} seeds per cell from x0 ~ N(0, (scale x 0.01)^2) on xc, alpha, theta (eki-dip's initial "
        f"states). MPC: horizon {cfg.horizon}, DARE terminal cost, Q and R of Table 3.1; LQR: the discrete LQR "
        "of the same model, clipped; RP: (2.14) with the library's P, clipped. Stabilised: no divergence and "
        "max |alpha|, |theta| over the last second below 0.02 rad. 95% intervals: Wilson for fractions, normal "
        "for means.",
        "",
        "| x0 scale | controller | stabilised | diverged | mean abs u (V) | track violations | cost |",
        "|---|---|---|---|---|---|---|",
    ]
    for sc, row in r["table"].items():
        for name in NAMES:
            c = row[name]
            u = fmt_ci(c["mean_abs_u"], c["mean_abs_u_ci95"], 3) if "mean_abs_u" in c else "-"
            cost = fmt_ci(c["cost"], c["cost_ci95"], 3) if "cost" in c else "-"
            lines.append(f"| {sc} | {name} | {fmt_ci(c['stabilized_fraction'], c['stabilized_fraction_ci95'], 3)} | "
                         f"{c['diverged']} | {u} | "
                         f"{fmt_ci(c['track_violation_fraction'], c['track_violation_fraction_ci95'], 3)} | {cost} |")
    qp = [f"{sc} {n}: {row[n]['qp_unsolved_periods']} (most iterations {row[n]['qp_max_iterations']})"
          for sc, row in r["table"].items() for n in ("mpc", "mpc_tuned")]
    lines += ["", f"MPC periods whose QP stopped at the iteration limit ({cfg.qp_max_iter}) before it was solved, "
              "summed over the seeds: " + "; ".join(qp) + "."]
    lines += ["", "Which controller wins where (highest stabilised fraction; a tie where the unpaired intervals "
              "overlap): " + "; ".join(f"{sc}: {_winner(row)}" for sc, row in r["table"].items()) + "."]
    lines += ["", "Paired on the same initial states (each seed's stabilised indicator, MPC minus the other; "
              "normal 95% interval over seeds): " + "; ".join(
                  f"{sc}: " + ", ".join(f"{k[len('mpc_minus_'):]} {fmt_ci(v['stabilized_fraction'], v['stabilized_fraction_ci95'], 3)}"
                                        for k, v in row.items()) for sc, row in r["paired"].items()) + "."]
    ahead = [sc for sc, row in r["paired"].items() if all(v["stabilized_fraction_ci95"][0] > 0 for v in row.values())]
    lines += ["", "Paired, the MPC stabilises more seeds than every other controller at "
              + (", ".join(ahead) if ahead else "no scale") + "; elsewhere some paired interval contains 0."]
    t = r["tuning"]
    lines += ["", "## MPC weights tuned by gradient",
              "", f"Adam on log-weights, {t['steps']} steps, mean closed-loop cost over {cfg.tune_seeds} seeds at "
              f"scale {cfg.tune_scale:g}, {cfg.tune_duration} s (implicit QP gradients through the loop):",
              "", "| | q_xc | q_alpha | q_theta | r | tuning cost |", "|---|---|---|---|---|---|",
              f"| LQR's (Table 3.1) | {' | '.join(f'{v:.4g}' for v in t['lqr_weights']['q'])} | "
              f"{t['lqr_weights']['r']:.4g} | {t['cost_before']:.5g} |",
              f"| tuned MPC | {' | '.join(f'{v:.4g}' for v in t['tuned_weights']['q'])} | "
              f"{t['tuned_weights']['r']:.4g} | {t['cost_after']:.5g} |"]
    return "\n".join(lines)


EXPERIMENT = Experiment(
    id="dip-mpc",
    title="DIP with a motor limit: constrained MPC vs saturated LQR and relaxed projection (extension)",
    config_cls=DipMpcConfig,
    run=run,
    quick={"seeds": 16, "duration": 1.0, "x0_scales": [1.0, 8.0], "tune_steps": 2, "tune_seeds": 4,
           "tune_duration": 0.5},
    source="extension beyond the documents (MPC with the actuator limit as a constraint)",
    reproduce=False,
    quick_cost_s=30,
)
