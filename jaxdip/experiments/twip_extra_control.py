"""twip-extra-control: LQR + two-layer-network extra control against LQR alone on the TWIP (Stumfoll §8.2).

Closed loop per sample (``jaxdip.sim.loop``): the true state -> tilt output (backlash (161) on phi in the
``deadzone_backlash`` case, identity otherwise) -> passthrough estimator -> controller
(``jaxdip.control.extra_control``: u = sat(u_nom + u_e), or LQR alone with u_e switched off) -> deadzone (160)
on the voltage in the deadzone cases -> the nonlinear TWIP (72)-(73) plus the unmodeled accelerations d1, d2
of (185) over dt by RK4 sub-steps.

Design (all systems): the discrete LQR (``jaxdip.control.twip_lqr``) on the nominal linear model (79) with
Table 8.1, R = 1, Q = diag(1, 1, 0.1, 0.1) (180)-(181); desired trajectory (182)-(183) with x2d = 0.1 m/s,
x1d(0) = 0, x3d and u_d from the same nominal model; every control signal clipped at +-11.1 V.

Cases (results keys) and the three systems of each (Table 8.3's columns):
  param               truth Table 8.2                                   (§8.2.1)
  unmodeled           truth Table 8.2 + d1 = 1/2 x' sin(180 x/pi), d2 = 1/4 x'^2 (185)   (§8.2.2)
  unmodeled_unstable  as unmodeled with the gains 1/2 -> 3/4 and 1/4 -> 2/5 (Fig. 8.18)
  deadzone            truth ``nonlinear_truth`` (Table 8.2 by default, see below) + deadzone +-0.5 V (§8.2.3)
  deadzone_backlash   as deadzone + backlash +-0.1 deg, m = 1, on the tilt the controller sees (§8.2.4)
  systems: lqr = perturbed truth, LQR; extra = perturbed truth, LQR + extra control; nominal = Table 8.1 truth
  without unmodeled dynamics, LQR (the "nominal system optimal control"), with the case's deadzone/backlash.

Decisions: (185)'s d1, d2 are added to x'' and phi'' of the nonlinear plant, as they enter (87); "sin(180x/pi)"
is taken as printed (frequency ``d1_freq`` = 180/pi rad/m); "gains 3/4 and 2/5" replace the coefficients 1/2 and
1/4 of d1 and d2. §8.2.3 says the deadzone study "removes the parameter uncertainty", but Table 8.3 then gives
different scores to the perturbed-LQR (358.42) and nominal (326.10) columns, which would be equal if both
plants were Table 8.1; we therefore keep Table 8.2 as the perturbed truth there (``nonlinear_truth``).

The extra control's main law is the "flat" variant of ``jaxdip.control.extra_control`` (virtual control through
the flat output, derived because (93) as printed commands the tilt with the wrong sign and every seed falls) with
the thesis's numbers (k1 = k2 = 2.5, gamma = 0.1, sigma = 0.01). ``variants`` runs further LQR + extra rows on the
same seeds, each changing a few controller keys: by default the printed law, the networks switched off
(gamma = 0: what the networks contribute) and k1 = 10 (from a grid over k1 on 100 seeds: the smallest of 2.5,
5, 7.5, 10 that kept every unmodeled_unstable seed up with room to spare).

Score (Table 8.3): sum over the samples k = 0 .. N-1 (N = duration/dt, default 20 s at 0.01 s: 2000 terms) of
the Euclidean norm ||x_k - x_d,k|| of the true state's difference from the desired trajectory (mixed units
m, m/s, rad, rad/s, as in the thesis). Seeds: seed i draws the networks' random input weights V1, V2 and, for
i > 0, the initial state x0 * (1 + U(-s, s)) per component (seed 0 starts at (184)); the three systems of a
case share each seed's x0 and V. A seed whose |phi| passes ``tilt_bound_deg`` or whose state leaves the bounds
is diverged; scores are averaged over the others. improvement = 1 - mean(extra) / mean(lqr).

``score_fn`` is the mean param score as a differentiable function of the controller's parameters (k1, k2,
learning rates; gradient checked against finite differences in tests/test_extra_control.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.resources import Load, steps_of
from jaxdip import config as C
from jaxdip import stats
from jaxdip.control.extra_control import ExtraControlParams, desired_state, extra_control, extra_control_params
from jaxdip.control.twip_lqr import twip_dlqr
from jaxdip.estimators.passthrough import passthrough
from jaxdip.experiments import register, twip_dmso
from jaxdip.experiments.base import Experiment, Outcome, RunContext
from jaxdip.plants import twip
from jaxdip.plants.base import Plant
from jaxdip.progress import Progress
from jaxdip.sim import Loop, LoopParams
from jaxdip.sim.actuators import BacklashParams, DeadzoneParams, backlash_component, deadzone_component
from jaxdip.sim.component import Component
from jaxdip.sim.loop import init_carry, make_step, rollout
from jaxdip.sim.montecarlo import seed_key

CASES = ("param", "unmodeled", "unmodeled_unstable", "deadzone", "deadzone_backlash")
SYSTEMS = ("lqr", "extra", "nominal")
STATES = twip.STATE_NAMES
DEG = math.pi / 180.0
# Table 8.3 (the thesis has no unmodeled_unstable row)
THESIS = {
    "param": {"lqr": 248.92, "extra": 123.07, "nominal": 240.72},
    "unmodeled": {"lqr": 587.04, "extra": 235.35, "nominal": 240.72},
    "deadzone": {"lqr": 358.42, "extra": 181.53, "nominal": 326.10},
    "deadzone_backlash": {"lqr": 1451.9, "extra": 688.17, "nominal": 1434.5},
}
# the controller's own keys: a variant changes numbers in ExtraControlParams only (no recompilation)
VARIANT_KEYS = ("virtual", "k1", "k2", "gamma", "sigma", "b", "v_scale", "tau_d")
DEFAULT_VARIANTS = ("virtual=printed", "gamma=[0.0, 0.0, 0.0, 0.0]", "k1=10.0")
FIGS = {"param": ("8.15", "8.16"), "unmodeled": ("8.17", "8.19"), "unmodeled_unstable": ("8.18", "8.19"),
        "deadzone": ("8.20", "8.21"), "deadzone_backlash": ("8.22", "8.23")}


@dataclass
class TwipExtraControlConfig:
    seeds: int = C.field(1000, C.positive, doc="Monte Carlo seeds per case (network input weights, x0 spread)")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    cases: list[str] = C.field(list(CASES), doc="which of " + ", ".join(CASES) + " to run")
    duration: float = C.field(20.0, C.positive_finite, doc="simulated time (s); the score sums duration/dt samples")
    dt: float = C.field(0.01, C.positive_finite, doc="control period (s); also the Euler step of the weight laws")
    substeps: int = C.field(10, C.positive, doc="RK4 sub-steps of the true plant per control period")
    x0: list[float] = C.field([1.0, 0.3, 10.0, 1.0], C.finite, C.length(4),
                              doc="initial state [m, m/s, deg, deg/s] (184)")
    init_spread: float = C.field(0.1, C.nonneg_finite,
                                 doc="seed i > 0 starts at x0 * (1 + U(-s, s)) per component")
    v_d: float = C.field(0.1, C.finite, doc="desired constant velocity (m/s) (182)")
    lqr_Q: list[float] = C.field([1.0, 1.0, 0.1, 0.1], C.nonneg_finite, C.length(4),
                                 doc="LQR state weights on [x, x_dot, phi, phi_dot] (181)")
    lqr_R: float = C.field(1.0, C.positive_finite, doc="LQR input weight (180)")
    feedforward: bool = C.field(True, doc="u_nom includes the desired input u_d of (183) (false: (84) literally)")
    u_max: float = C.field(11.1, C.positive_finite, doc="saturation of every control signal (V), §7.5.1")
    k1: float = C.field(2.5, C.finite, doc="virtual-control gain k1 (93)")
    k2: float = C.field(2.5, C.finite, doc="extra-control gain k2 (101)")
    n_hidden: int = C.field(10, C.positive, doc="hidden neurons per layer of each network")
    b: float = C.field(1.0, C.finite, doc="entries of the coefficient vectors B1 = B2 of (111), (113)")
    gamma: list[float] = C.field([0.1, 0.1, 0.1, 0.1], C.nonneg_finite, C.length(4),
                                 doc="learning rates [gamma11, gamma12, gamma21, gamma22] (111)-(114)")
    sigma: list[float] = C.field([0.01, 0.01, 0.01, 0.01], C.nonneg_finite, C.length(4),
                                 doc="damping [sigma11, sigma12, sigma21, sigma22] (111)-(114)")
    v_scale: float = C.field(1.0, C.nonneg_finite, doc="random input weights V1, V2 ~ U(-v_scale, v_scale)")
    virtual: str = C.field("flat", C.one_of("printed", "effective", "flat"),
                           doc="virtual tilt (93): printed (A2), effective (A2 - B1 A4/B2), flat (that gain, flat-output "
                               "errors; see jaxdip.control.extra_control)")
    tau_d: float = C.field(0.05, C.nonneg_finite,
                           doc="time constant (s) of the filtered difference giving xbar4 = d xbar3/dt (0: raw)")
    d_gains: list[float] = C.field([0.5, 0.25], C.finite, C.length(2), doc="coefficients of d1, d2 (185)")
    d_gains_unstable: list[float] = C.field([0.75, 0.4], C.finite, C.length(2),
                                            doc="coefficients of d1, d2 in unmodeled_unstable (Fig. 8.18)")
    d1_freq: float = C.field(180.0 / math.pi, C.finite, doc="d1 = g1 x' sin(d1_freq x) (185; printed 180/pi)")
    deadzone: float = C.field(0.5, C.nonneg_finite, doc="deadzone half-width (V), d- = -d, d+ = d (160)")
    backlash_deg: float = C.field(0.1, C.nonneg_finite, doc="backlash half-width on the tilt (deg), m = 1 (162)")
    nonlinear_truth: str = C.field("table_8_2", C.one_of("table_8_1", "table_8_2"),
                                   doc="perturbed truth of the deadzone cases (see the module doc)")
    tilt_bound_deg: float = C.field(90.0, C.positive_finite, doc="|phi| above this counts as a fall (diverged)")
    state_bound: list[float] = C.field([100.0, 50.0, 1000.0, 1000.0], C.positive, C.length(4),
                                       doc="|x|, |x_dot|, -, |phi_dot| above these count as diverged (phi: tilt_bound_deg)")
    variants: list[str] = C.field(list(DEFAULT_VARIANTS),
                                  doc="further LQR + extra rows on the same seeds, each 'key=value; key=value' over "
                                      "the controller keys " + ", ".join(VARIANT_KEYS))
    chunk_seeds: int = C.field(250, C.positive, doc="seeds per compiled batch")

    def loads(self) -> list[Load]:
        n = steps_of(self.duration, self.dt)
        return [Load("the Monte Carlo", ("seeds", "duration"), self.seeds, n, saved=24 * n,
                     state=64 * self.n_hidden + 256)]

    def validate(self):
        for i, spec in enumerate(self.variants):
            try:
                variant_config(self, spec)
            except C.ConfigError as e:
                raise C.ConfigError(f"variants[{i}]", str(e)) from None
        if not self.cases:
            raise C.ConfigError("cases", "must name at least one case")
        for i, c in enumerate(self.cases):
            if c not in CASES:
                raise C.ConfigError(f"cases[{i}]", f"must be one of {', '.join(map(repr, CASES))}")
        if self.duration < 2 * self.dt:
            raise C.ConfigError("duration", f"must cover at least two samples (dt = {self.dt})")


def variant_config(cfg, spec: str):
    """``cfg`` with the overrides of one ``variants`` entry ('k1=10; virtual=printed') applied and checked."""
    data = C.to_dict(cfg)
    data["variants"] = []
    items = [t.strip() for t in spec.split(";") if t.strip()]
    if not items:
        raise C.ConfigError(repr(spec), "a variant needs at least one key=value")
    for item in items:
        k, v = C.parse_set(item)
        if k not in VARIANT_KEYS:
            raise C.ConfigError(k, f"a variant may set only {', '.join(VARIANT_KEYS)}")
        data[k] = v
    return C.from_dict(type(cfg), data)


# ---- the plant with unmodeled dynamics (185) -------------------------------------------------------------


class TwipUnmodeledParams(NamedTuple):
    twip: twip.TWIPParams
    g1: jnp.ndarray  # d1 = g1 x' sin(freq x)
    g2: jnp.ndarray  # d2 = g2 x'^2
    freq: jnp.ndarray


def unmodeled(p: TwipUnmodeledParams, x):
    """(d1, d2) of (185)."""
    return p.g1 * x[1] * jnp.sin(p.freq * x[0]), p.g2 * x[1] ** 2


def f_unmodeled(p: TwipUnmodeledParams, x, u):
    d1, d2 = unmodeled(p, x)
    return twip.f(p.twip, x, u) + jnp.stack([jnp.zeros(()), d1, jnp.zeros(()), d2])


def plant() -> Plant:
    return Plant(name="twip-unmodeled", state_names=STATES, input_names=("V",),
                 default_params=lambda: TwipUnmodeledParams(twip.default_params(), 0.0, 0.0, 180 / math.pi),
                 f=f_unmodeled)


def tilt_backlash() -> Component:
    """Output backlash (161) on the tilt: y = x with phi replaced by the backlash output."""
    bl = backlash_component(1)

    def step(p, s, x, key, k):
        s, psi = bl.step(p, s, x[2:3], key, k)
        return s, x.at[2].set(psi[0])

    return Component(bl.init, step)


# ---- building the loops ----------------------------------------------------------------------------------


def build_loop(cfg: TwipExtraControlConfig) -> Loop:
    """One loop structure for every case and system (the differences are numbers in ``LoopParams``)."""
    return Loop(plant=plant(), dt=cfg.dt, sensor=tilt_backlash(), estimator=passthrough,
                controller=extra_control(cfg.n_hidden), actuator=deadzone_component(), substeps=cfg.substeps)


def controller_params(cfg: TwipExtraControlConfig, extra: float) -> ExtraControlParams:
    d = twip_dlqr(twip.default_params(), Q=tuple(cfg.lqr_Q), R=cfg.lqr_R, dt=cfg.dt)
    p = extra_control_params(d.K, d.A, d.B, dt=cfg.dt, v_d=cfg.v_d, k1=cfg.k1, k2=cfg.k2, n_hidden=cfg.n_hidden,
                             b=cfg.b, gamma=0.0, sigma=0.0, u_max=cfg.u_max, extra=extra, v_scale=cfg.v_scale,
                             ff=1.0 if cfg.feedforward else 0.0, tau_d=cfg.tau_d, virtual=cfg.virtual)
    g, s = [jnp.asarray(v, jnp.float64) for v in cfg.gamma], [jnp.asarray(v, jnp.float64) for v in cfg.sigma]
    return p._replace(gamma11=g[0], gamma12=g[1], gamma21=g[2], gamma22=g[3],
                      sigma11=s[0], sigma12=s[1], sigma21=s[2], sigma22=s[3])


def loop_params(cfg: TwipExtraControlConfig, case: str, system: str) -> LoopParams:
    nominal = system == "nominal"
    if nominal:
        truth = twip.default_params()
    elif case.startswith("deadzone"):
        truth = twip.default_params() if cfg.nonlinear_truth == "table_8_1" else twip.perturbed_params()
    else:
        truth = twip.perturbed_params()
    g = (0.0, 0.0)
    if not nominal and case == "unmodeled":
        g = cfg.d_gains
    if not nominal and case == "unmodeled_unstable":
        g = cfg.d_gains_unstable
    f64 = partial(jnp.asarray, dtype=jnp.float64)
    pp = TwipUnmodeledParams(twip.TWIPParams(*[f64(v) for v in truth]), f64(g[0]), f64(g[1]), f64(cfg.d1_freq))
    dz = cfg.deadzone if case.startswith("deadzone") else 0.0
    bl = cfg.backlash_deg * DEG if case == "deadzone_backlash" else 0.0
    bound = jnp.asarray([cfg.state_bound[0], cfg.state_bound[1], cfg.tilt_bound_deg * DEG, cfg.state_bound[3]])
    return LoopParams(plant=pp, sensor=BacklashParams(f64(1.0), f64(-bl), f64(bl)),
                      estimator=(), controller=controller_params(cfg, 1.0 if system == "extra" else 0.0),
                      actuator=DeadzoneParams(f64(-dz), f64(dz)), state_bound=bound)


def x0_thesis(cfg: TwipExtraControlConfig):
    return twip_dmso.x0_thesis(cfg)  # same (184) = (179) convention: [m, m/s, deg, deg/s] in the config


def initial_state(x0, spread, i, key):
    # the DMSO experiment's spread of initial states, on this experiment's own fold of the seed key
    return twip_dmso.initial_state(x0, spread, i, jax.random.fold_in(key, 0))


def n_steps(cfg: TwipExtraControlConfig) -> int:
    return int(round(cfg.duration / cfg.dt))


def score_of(lp: LoopParams, xs, dt):
    """Table 8.3's score: sum_k ||x_k - x_d,k|| over the recorded true states (k = 0 .. N-1)."""
    t = jnp.arange(xs.shape[0]) * dt
    return jnp.sum(jnp.linalg.norm(xs - desired_state(lp.controller, t), axis=-1))


def simulate_seed(loop: Loop, lp: LoopParams, n: int, x0, spread, i, base_key):
    sk = seed_key(base_key, i)
    x0i = initial_state(x0, spread, i, sk)
    carry, rec = rollout(loop, lp, x0i, sk, n, record_every=1, record_fn=lambda r: r.x)
    return score_of(lp, rec, loop.dt), carry.diverged


def seed_scores(cfg: TwipExtraControlConfig):
    """(LoopParams, x0, spread, seed indices, key) -> (scores, diverged), vmapped over the seeds, not jitted
    (the one per-seed Monte Carlo map of this experiment: batches, ``score_fn`` and the tune target use it)."""
    loop = build_loop(cfg)
    n = n_steps(cfg)
    return jax.vmap(lambda lp, x0, spread, i, key: simulate_seed(loop, lp, n, x0, spread, i, key),
                    in_axes=(None, None, None, 0, None))


def batch_fn(cfg: TwipExtraControlConfig):
    return jax.jit(seed_scores(cfg))


def score_fn(cfg: TwipExtraControlConfig, case: str = "param", system: str = "extra", n_seeds: int = 1):
    """(controller params -> mean score over seeds 0..n_seeds-1): the differentiable objective of a tuner."""
    scores = seed_scores(cfg)
    lp0 = loop_params(cfg, case, system)
    x0 = x0_thesis(cfg)
    key = jax.random.PRNGKey(cfg.seed)

    def J(cp: ExtraControlParams):
        s, _ = scores(lp0._replace(controller=cp), x0, cfg.init_spread, jnp.arange(n_seeds), key)
        return jnp.mean(s)

    return J, lp0.controller


class Trace(NamedTuple):
    x: jnp.ndarray
    u: jnp.ndarray
    u_nom: jnp.ndarray
    u_e: jnp.ndarray


def trace_fn(cfg: TwipExtraControlConfig, i: int = 0):
    """(LoopParams -> Trace): one seed's trajectory with the controller's split of u into u_nom and u_e
    (for the figures); compiled once, reused for every case and system."""
    loop = build_loop(cfg)
    n = n_steps(cfg)
    key = jax.random.PRNGKey(cfg.seed)

    @jax.jit
    def go(lp):
        sk = seed_key(key, i)
        x0i = initial_state(x0_thesis(cfg), cfg.init_spread, i, sk)
        step = make_step(loop, n)

        def body(c, _):
            c2, rec = step(lp, sk, c)
            return c2, Trace(rec.x, rec.u[0], c2.controller.u_nom, c2.controller.u_e)

        return jax.lax.scan(body, init_carry(loop, lp, x0i, sk), None, length=n)[1]

    return lambda lp: jax.tree_util.tree_map(np.asarray, go(lp))


# ---- running, summarising, reporting ---------------------------------------------------------------------


def run_system(cfg, fn, lp, bar=None):
    x0 = x0_thesis(cfg)
    key = jax.random.PRNGKey(cfg.seed)
    scores, divs = [], []
    for start in range(0, cfg.seeds, cfg.chunk_seeds):
        idx = jnp.arange(start, min(cfg.seeds, start + cfg.chunk_seeds))
        pad = cfg.chunk_seeds - idx.shape[0] if cfg.seeds > cfg.chunk_seeds else 0
        idx_p = jnp.concatenate([idx, jnp.repeat(idx[-1:], pad)]) if pad else idx
        s, d = fn(lp, x0, cfg.init_spread, idx_p, key)
        scores.append(np.asarray(s)[: idx.shape[0]])
        divs.append(np.asarray(d)[: idx.shape[0]])
        if bar is not None:
            bar.update(int(idx.shape[0]))
    return np.concatenate(scores), np.concatenate(divs)


def versus_lqr(s, d, lqr_s, lqr_d) -> dict:
    """improvement = 1 - mean score / LQR's (each over its own non-diverged seeds), and its paired form over the
    seeds where neither diverged."""
    out = {"improvement": 1.0 - stats.mean_ci(s, ~d)[0] / stats.mean_ci(lqr_s, ~lqr_d)[0]}
    ok = ~d & ~lqr_d
    if ok.any():
        out["improvement_paired_mean"], out["improvement_paired_ci95"] = stats.mean_ci(1.0 - s[ok] / lqr_s[ok])
    return out


def summarize_case(scores: dict, divs: dict) -> dict:
    out = {}
    for sysname in SYSTEMS:
        s, d = scores[sysname], divs[sysname]
        m, ci = stats.mean_ci(s, ~d)
        med = float(np.median(s[~d])) if (~d).any() else float("nan")
        frac, fci = stats.wilson(int(d.sum()), len(d))
        out[sysname] = {"score_mean": m, "score_ci95": ci, "score_median": med, "score_seed0": float(s[0]),
                        "diverged": int(d.sum()), "diverged_fraction": frac, "diverged_fraction_ci95": fci}
    out.update(versus_lqr(scores["extra"], divs["extra"], scores["lqr"], divs["lqr"]))
    ok = ~divs["lqr"] & ~divs["extra"]
    if ok.any():
        out["extra_better_fraction"] = float(np.mean(scores["extra"][ok] < scores["lqr"][ok]))
    out["extra_bounded_fraction"] = float(np.mean(~divs["extra"]))
    out["lqr_diverged_fraction"] = float(np.mean(divs["lqr"]))
    return out


def fig_case(case, traces: dict, cfg):
    import matplotlib.pyplot as plt

    n = traces["lqr"].x.shape[0]
    t = np.arange(n) * cfg.dt
    cp = controller_params(cfg, 1.0)
    xd = np.asarray(desired_state(cp, t))
    scale = (1.0, 1.0, 1 / DEG, 1 / DEG)
    units = ("m", "m/s", "deg", "deg/s")
    labels = {"lqr": "Perturbed system", "extra": "Perturbed system with ue", "nominal": "Nominal system"}
    fs, fsn = FIGS[case]
    fig, axes = plt.subplots(4, 1, figsize=(7, 8), sharex=True)
    for j, ax in enumerate(axes):
        for sysname in SYSTEMS:
            ax.plot(t, traces[sysname].x[:, j] * scale[j], lw=1.0, label=labels[sysname])
        ax.plot(t, xd[:, j] * scale[j], "k--", lw=0.8, label="desired")
        ax.set_ylabel(f"{STATES[j]} ({units[j]})")
        ax.grid(alpha=0.3)
    lim = 5 * max(abs(cfg.x0[2]), 1.0)
    axes[2].set_ylim(-lim, lim)
    axes[0].legend(fontsize=7, loc="best")
    axes[0].set_title(f"{case}: states, seed 0 (cf. Fig. {fs})")
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig2, ax = plt.subplots(figsize=(7, 3.2))
    ax.plot(t, traces["nominal"].u, lw=1.0, label="optimal control (nominal system)")
    ax.plot(t, traces["extra"].u_nom, lw=1.0, label="nominal control u_nom")
    ax.plot(t, traces["extra"].u_e, lw=1.0, label="extra control u_e")
    ax.plot(t, traces["extra"].u, lw=1.0, label="total control")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("V")
    ax.set_title(f"{case}: control signals, seed 0 (cf. Fig. {fsn})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig2.tight_layout()
    return fig, fig2


def summarize_variant(s, d, lqr_s, lqr_d) -> dict:
    m, ci = stats.mean_ci(s, ~d)
    return {"score_mean": m, "score_ci95": ci, "diverged": int(d.sum()), "bounded_fraction": float(np.mean(~d)),
            **versus_lqr(s, d, lqr_s, lqr_d)}


def run(cfg: TwipExtraControlConfig, ctx: RunContext | None = None, progress: bool = True) -> Outcome:
    fn = batch_fn(cfg)
    trace = trace_fn(cfg, 0)
    results, figures = {}, {}
    vcfgs = {spec: variant_config(cfg, spec) for spec in cfg.variants}
    bar = Progress(len(cfg.cases) * (len(SYSTEMS) + len(vcfgs)) * cfg.seeds, desc="twip-extra-control",
                   enabled=progress)
    for case in cfg.cases:
        scores, divs, traces = {}, {}, {}
        for sysname in SYSTEMS:
            lp = loop_params(cfg, case, sysname)
            scores[sysname], divs[sysname] = run_system(cfg, fn, lp, bar)
            traces[sysname] = trace(lp)
        results[case] = summarize_case(scores, divs)
        results[case]["variants"] = {
            spec: summarize_variant(*run_system(cfg, fn, loop_params(vc, case, "extra"), bar), scores["lqr"],
                                    divs["lqr"]) for spec, vc in vcfgs.items()}
        fs, fc = fig_case(case, traces, cfg)
        figures[f"twip-extra-{case}-states"] = fs
        figures[f"twip-extra-{case}-control"] = fc
    bar.close()
    figures["twip-extra-variants"] = fig_variants(cfg, results)
    imps = [results[c]["improvement"] for c in cfg.cases if c in THESIS]
    results["mean_improvement_table_cases"] = float(np.mean(imps)) if imps else float("nan")
    results["horizon_s"] = cfg.duration
    results["dt_s"] = cfg.dt
    results["score_terms"] = n_steps(cfg)
    return Outcome(results=results, report=report(cfg, results), figures=figures)


def fig_variants(cfg, r):
    """Improvement over LQR alone and fraction of seeds kept up, per case, for the main law and every variant."""
    import matplotlib.pyplot as plt

    rows = [(f"{cfg.virtual} (main)", lambda c: r[c]["improvement"], lambda c: r[c]["extra_bounded_fraction"])]
    for spec in cfg.variants:
        rows.append((spec, lambda c, sp=spec: r[c]["variants"][sp]["improvement"],
                     lambda c, sp=spec: r[c]["variants"][sp]["bounded_fraction"]))
    rows.append(("LQR alone", lambda c: 0.0, lambda c: 1.0 - r[c]["lqr_diverged_fraction"]))
    cases = list(cfg.cases)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    w = 0.8 / len(rows)
    xs = np.arange(len(cases))
    for j, (name, imp, up) in enumerate(rows):
        off = xs - 0.4 + (j + 0.5) * w
        axes[0].bar(off, [100 * np.nan_to_num(imp(c), nan=0.0) for c in cases], w, label=name)
        for c, case in enumerate(cases):  # no score to show: every seed fell
            if not np.isfinite(imp(case)):
                axes[0].text(off[c], 1, "all fell", rotation=90, fontsize=6, ha="center", va="bottom")
        axes[1].bar(off, [100 * up(c) for c in cases], w, label=name)
    for c, case in enumerate(cases):
        if case in THESIS:
            th = 100 * (1 - THESIS[case]["extra"] / THESIS[case]["lqr"])
            axes[0].plot([c - 0.4, c + 0.4], [th, th], "k--", lw=1, label="thesis" if c == 0 else None)
    axes[0].set_ylabel("improvement over LQR (%)")
    axes[0].set_title("1 - mean score / LQR's (non-diverged seeds)")
    axes[1].set_ylabel("seeds kept up (%)")
    axes[1].set_title(f"bounded over {cfg.duration:g} s, {cfg.seeds} seeds")
    for ax in axes:
        ax.set_xticks(xs, cases, rotation=20, fontsize=8)
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(alpha=0.3, axis="y")
    axes[1].set_ylim(0, 105)
    axes[0].set_ylim(-60, 70)
    axes[0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return fig


def _g(v, d=4):
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{d}g}"


def report(cfg: TwipExtraControlConfig, r: dict) -> str:
    out = [f"Score = sum over k = 0..{n_steps(cfg) - 1} of ||x_k - x_d,k|| ({cfg.duration:g} s at dt = {cfg.dt:g} s), "
           f"mean [95% interval] over the non-diverged of {cfg.seeds} seeds (network input weights and "
           f"x0 * (1 +- {cfg.init_spread:g}) vary; seed 0 = the thesis's x0). Thesis: one run per cell.", "",
           "| case | LQR (ours) | LQR (thesis) | LQR + extra (ours) | LQR + extra (thesis) | nominal (ours) "
           "| nominal (thesis) | improvement ours / thesis | diverged LQR / extra / nominal |",
           "|---|---|---|---|---|---|---|---|---|"]
    for case in cfg.cases:
        c = r[case]
        th = THESIS.get(case, {})
        cells = []
        for s in SYSTEMS:
            cells.append(f"{_g(c[s]['score_mean'])} [{_g(c[s]['score_ci95'][0])}, {_g(c[s]['score_ci95'][1])}]")
            cells.append(_g(th.get(s)))
        th_imp = 1 - th["extra"] / th["lqr"] if th else None
        out.append(f"| {case} | " + " | ".join(cells) + f" | {_g(c['improvement'], 3)} / {_g(th_imp, 3)} | "
                   + " / ".join(str(c[s]["diverged"]) for s in SYSTEMS) + " |")
    out += ["", f"Mean improvement over the thesis's four cases: ours {_g(r['mean_improvement_table_cases'], 3)}, "
            f"thesis 0.531 (its 53.1%). Main extra control: virtual = {cfg.virtual}, k1 = {cfg.k1:g}, "
            f"k2 = {cfg.k2:g}, gamma = {cfg.gamma}.", ""]
    for case in cfg.cases:
        c = r[case]
        extra_best = c["extra"]["score_mean"] < min(c["lqr"]["score_mean"], c["nominal"]["score_mean"])
        line = (f"- {case}: extra control best of the three: {'yes' if extra_best else 'no'}; "
                f"extra better than LQR in {_g(100 * c.get('extra_better_fraction', float('nan')), 3)}% of seeds; "
                f"LQR diverged in {_g(100 * c['lqr_diverged_fraction'], 3)}%, LQR + extra bounded in "
                f"{_g(100 * c['extra_bounded_fraction'], 3)}% of seeds.")
        out.append(line)
    if cfg.variants:
        out += ["", "Variants of the extra control on the same seeds (`variants`; each changes only the listed keys "
                    "of the main law):", "",
                "| case | variant | score mean [95%] | improvement vs LQR (paired [95%]) | bounded |",
                "|---|---|---|---|---|"]
        for case in cfg.cases:
            for spec, v in r[case]["variants"].items():
                pair = (f" ({_g(v['improvement_paired_mean'], 3)} [{_g(v['improvement_paired_ci95'][0], 3)}, "
                        f"{_g(v['improvement_paired_ci95'][1], 3)}])" if "improvement_paired_mean" in v else "")
                out.append(f"| {case} | `{spec}` | {_g(v['score_mean'])} [{_g(v['score_ci95'][0])}, "
                           f"{_g(v['score_ci95'][1])}] | {_g(v['improvement'], 3)}{pair} | "
                           f"{_g(100 * v['bounded_fraction'], 3)}% |")
    return "\n".join(out)


EXPERIMENT = register(Experiment(
    id="twip-extra-control",
    title="TWIP: two-layer-network extra control for unmatched uncertainty vs LQR",
    config_cls=TwipExtraControlConfig,
    run=run,
    quick={"seeds": 8, "duration": 10.0, "chunk_seeds": 8},
    source="Stumfoll MS thesis §6.2 (eqs. 86-114) and §8.2 (eqs. 179-185, Table 8.3, Figs. 8.15-8.23)",
))
