"""dip-lqr: the DIP (printed model) under continuous LQR held over 1 ms periods, at Monte Carlo scale.

The controller is the LQR of thesis §3.2 (eq. 3.4) designed on the model's linearisation at upright with
Q = diag(30, 350, 100, 0, 0, 0) on [xc, alpha, theta, ...] and R = 0.1 (the weights Table 3.1 used on the
laboratory system). Every state is measured with white Gaussian noise; initial states are uniform in a small
ball around upright.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np

import jaxdip as jd
from jaxdip.resources import Load, steps_of
from jaxdip import config as C
from jaxdip.runner.experiment import Experiment, Outcome, RunContext, precision_field
from jaxdip.runner.figures import band_figure
from jaxdip.runner.results import fmt_ci
from jaxdip.runner.summaries import failure_lines, loop_per_seed, loop_summary
from jaxdip.runner.weights import weight_matrix
from jaxdip.plants import dip
from jaxdip.scenarios.dip_lqr import dip_lqr

INF = float("inf")


@dataclass
class DipLqrConfig:
    seeds: int = C.field(4096, C.positive, doc="Monte Carlo seeds")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    variant: str = C.field("printed", C.one_of("printed", "lagrangian"), doc="DIP equations of motion")
    dt: float = C.field(0.001, C.positive_finite, doc="control period (s)")
    substeps: int = C.field(1, C.positive, doc="RK4 sub-steps per period (1: measured, docs/performance.md)")
    duration: float = C.field(6.5, C.positive_finite, doc="simulated time (s)")
    Q: list[float] | list[list[float]] = C.field([30.0, 350.0, 100.0, 0.0, 0.0, 0.0],
                                                doc="state weight on [xc, alpha, theta, xc_dot, alpha_dot, theta_dot]")
    R: float = C.field(0.1, C.positive_finite, doc="input weight")
    noise_std: list[float] = C.field([1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2], C.nonneg_finite, C.length(6),
                                     doc="measurement noise std per state (m, rad, m/s, rad/s)")
    init_radius: float = C.field(0.05, C.nonneg_finite, doc="initial states uniform in this ball around upright")
    state_bound: list[float] = C.field([1.0, 1.5708, 1.5708, INF, INF, INF], C.positive, C.length(6),
                                       doc="|x_i| above this counts as divergence")
    stabilized_tol: float = C.field(0.02, C.positive_finite,
                                    doc="stabilised: max |alpha|, |theta| over the last second below this (rad)")
    record_every: int = C.field(10, C.positive, doc="keep every n-th period for the figures")
    precision: str = precision_field()
    trig: str = C.field("vectorised", C.one_of("vectorised", "library"),
                        doc="the DIP's sin and cos: vectorised (within 3 ulp of the C library's, faster) or library")
    noise_draw: str = C.field("float32", C.one_of("float32", "loop"),
                              doc="dtype of the sensor's normals before the cast (loop: the loop's own; "
                                  "trig=library with noise_draw=loop is the stream dip-lqr drew before "
                                  "2026-11-26's change)")

    def loads(self) -> list[Load]:
        n = steps_of(self.duration, self.dt)
        return [Load("the Monte Carlo", ("seeds", "duration", "record_every"), self.seeds, n,
                     saved=2 * (n // self.record_every))]

    def validate(self):
        weight_matrix("Q", self.Q, 6)
        if self.duration < self.dt:
            raise C.ConfigError("duration", f"must be at least one period (dt = {self.dt})")
        steps = int(round(self.duration / self.dt))
        if steps % self.record_every:
            raise C.ConfigError("record_every", f"must divide the number of periods ({steps})")


def build(cfg: DipLqrConfig) -> jd.Rollout:
    """One Monte Carlo trial (the library's dip_lqr scenario with this config's values)."""
    r = dip_lqr(variant=cfg.variant, dt=cfg.dt, substeps=cfg.substeps, duration=cfg.duration,
                Q=weight_matrix("Q", cfg.Q, 6), R=cfg.R, noise_std=cfg.noise_std, init_radius=cfg.init_radius,
                state_bound=cfg.state_bound, record_every=cfg.record_every, trig=cfg.trig,
                noise_draw=cfg.noise_draw)
    return jd.with_precision(r, cfg.precision)


def simulate(cfg: DipLqrConfig, progress: bool = True, shard: bool | None = None) -> jd.Solution:
    return jd.monte_carlo(build(cfg), jax.random.PRNGKey(cfg.seed), cfg.seeds, shard=shard, progress=progress,
                          desc="dip-lqr")


def per_seed(cfg: DipLqrConfig, sol: jd.Solution):
    """The per-seed arrays behind ``summarize``; the saved angles as trajectories (seed, time, angle)."""
    data = loop_per_seed(sol, dip.STATE_NAMES, (1, 2), cfg.stabilized_tol, dt=cfg.dt, state_units=dip.STATE_UNITS,
                         input_units="V")
    data.coords["time"] = np.arange(np.shape(sol.saved)[1]) * cfg.dt * cfg.record_every
    data.coords["angle"] = ["alpha", "theta"]
    data.variables["saved"] = (("seed", "time", "angle"), np.asarray(sol.saved),
                               {"units": "rad", "long_name": "alpha and theta every record_every periods"})
    return data


def summarize(cfg: DipLqrConfig, sol: jd.Solution, data=None) -> dict:
    return loop_summary(sol, dip.STATE_NAMES, (1, 2), cfg.stabilized_tol, dt=cfg.dt, bound=cfg.state_bound,
                        per_seed=data)


# Thesis Table 3.1, LQR column: the laboratory system over a typical 20 s interval (units not printed).
THESIS_LQR_LAB = {"alpha": (3.4, 3.03), "theta": (1.9, 0.81), "xc": (29.4, 410.7), "u": (1.7, 1.5)}


def report(cfg: DipLqrConfig, r: dict) -> str:
    lines = [
        f"DIP ({cfg.variant} model) under continuous LQR, Q = {cfg.Q}, R = {cfg.R}, held for {cfg.dt * 1e3:g} ms "
        f"periods, {cfg.duration} s, noise std {cfg.noise_std}, initial states uniform in a ball of radius "
        f"{cfg.init_radius} around upright. The DIP's sin and cos: {cfg.trig}; the sensor's normals drawn in "
        f"{'the loop dtype' if cfg.noise_draw == 'loop' else cfg.noise_draw}.",
        "",
        f"- stabilised fraction: **{fmt_ci(r['stabilized_fraction'], r['stabilized_fraction_ci95'])}** "
        f"(max |alpha|, |theta| over the last second < {cfg.stabilized_tol} rad)",
        f"- diverged: {r['diverged']} of {cfg.seeds}",
        *failure_lines(r, cfg.seeds),
    ]
    if r["states"]:
        survivors = cfg.seeds - r["diverged"]
        lines += ["", f"Per-trajectory time averages, then mean over the {survivors} seeds that did not diverge, "
                  "with 95% intervals:", "", "| state | mean | var | mean abs |", "|---|---|---|---|"]
        for name, s in r["states"].items():
            lines.append(f"| {name} | {fmt_ci(s['mean'], s['mean_ci95'])} | {fmt_ci(s['var'], s['var_ci95'])} | "
                         f"{fmt_ci(s['mean_abs'], s['mean_abs_ci95'])} |")
        lines.append(f"| u (V) | | {fmt_ci(r['u']['var'], r['u']['var_ci95'])} | "
                     f"{fmt_ci(r['u']['mean_abs'], r['u']['mean_abs_ci95'])} |")
    lines += [
        "",
        "For orientation only: thesis Table 3.1 (LQR column) gives laboratory means/variances of |alpha| 3.4/3.03, "
        "|theta| 1.9/0.81, |xc| 29.4/410.7, |u| 1.7/1.5 over a typical 20 s interval on the real system, in units "
        "the thesis does not print (the magnitudes suggest mrad and mm). Those include encoder quantisation, "
        "friction and model error that this simulation does not have, so they are not expected to match.",
    ]
    return "\n".join(lines)


def run(cfg: DipLqrConfig, ctx: RunContext | None = None) -> Outcome:
    sol = simulate(cfg)
    data = per_seed(cfg, sol)
    results = summarize(cfg, sol, data)
    ok = np.asarray(sol.result) == jd.RESULTS.ok
    rec = np.asarray(sol.saved)[ok]  # (seeds, T, 2)
    t = np.arange(rec.shape[1]) * cfg.dt * cfg.record_every
    fig = band_figure(t, {"alpha": rec[:, :, 0], "theta": rec[:, :, 1]}, "(rad)",
                      title=f"dip-lqr: {int(ok.sum())} of {cfg.seeds} trajectories (diverged ones left out)")
    return Outcome(results=results, report=report(cfg, results), figures={"band_alpha_theta": fig}, per_seed=data)


EXPERIMENT = Experiment(
    id="dip-lqr",
    title="DIP under continuous LQR (Monte Carlo)",
    config_cls=DipLqrConfig,
    run=run,
    quick={"seeds": 64, "duration": 2.0},
    source="thesis §3.2 (LQR, eq. 3.4) with the Table 3.1 weights, on the Table 3.3 model",
    quick_cost_s=2, full_cost_s=14,
)
