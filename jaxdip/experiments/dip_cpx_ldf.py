"""dip-cpx-ldf: power-series control of the DIP fed by the centred proximal-point MHE (CPX) or by the low-pass
derivative filter (LDF) (paper §5 Table 1, thesis §3.3 Table 3.2, Fig. 3.5).

Loop (printed model, 1 kHz, ``jaxdip.sim.loop``): the encoders measure xc, alpha, theta (quantised, with white
noise, ``jaxdip.sim.dip_sensors``); the estimator gets (y_k, u_{k-1}); the power-series law (3.5) with
Q = xc 80, theta 300, alpha 100, velocities 0 (the paper's diag(80, 300, 100, 0, 0, 0) is on [xc, theta, alpha],
mapped here by name) and R = 0.5 computes u_k; the plant receives u_k plus an input disturbance (a per-trial
constant offset and white noise, ``jaxdip.sim.disturbance``).

CPX is ``cpx_qr`` on the ZOH discretisation of the model's linearisation at upright, x_hat_0 = 0 (as in the
paper). What it hands the controller is, by default, its one-step model prediction
x~_{k+1} = Phi x^_k + W u_{k-1} (the documents' x~_{k+2} in their indexing, with the last applied input held:
see ``jaxdip.estimators.cpx``); ``cpx_output = "current"`` hands x^_k instead. The LDF hands the measured
positions and the filtered derivatives (``jaxdip.estimators.ldf``).

Table 1 reports, for one laboratory run of 6.5 s, the signed time mean and the variance of each measured state,
xc in cm and the angles in degrees (variances in cm^2 and deg^2). We report the same per-trial statistics
averaged over seeds; because the disturbance is symmetric, the seed average of a signed mean is ~0, so we also
report the seed average of |trial mean|, which is what one laboratory run's mean should be compared with.

The gamma sweep runs CPX at each gamma of a log grid with the same compiled loop (gamma is a leaf of the
params pytree; the QR factor of H is computed from it inside ``init``), so the sweep compiles once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.resources import Load, steps_of
from jaxdip import config as C
from jaxdip import stats
from jaxdip.control.power_series import power_series_controller, ps_params
from jaxdip.estimators.cpx import CPXParams, cpx_qr
from jaxdip.estimators.ldf import dip_ldf_params, ldf
from jaxdip.estimators.run import filter_sequence
from jaxdip.experiments import register
from jaxdip.experiments.base import Experiment, Outcome, RunContext
from jaxdip.experiments.common import ball_sampler, fmt_ci, trajectory_summary, weight_matrix
from jaxdip.plants import dip
from jaxdip.progress import Progress
from jaxdip.sim import Loop, LoopParams, advance, init_carry, linearize, montecarlo, rollout, zoh
from jaxdip.sim import dip_sensors
from jaxdip.sim.disturbance import input_disturbance, input_disturbance_params
from jaxdip.theory.mhe import cpx_gamma_criterion

INF = float("inf")
DEG = 180.0 / math.pi
# paper Table 1 = thesis Table 3.2 (laboratory, one 6.5 s run): signed mean and variance; xc in cm, angles in deg
TABLE_1 = {"cpx": {"xc": (-0.002, 5.52), "alpha": (0.178, 35.2), "theta": (-0.45, 3.89)},
           "ldf": {"xc": (-0.119, 5.98), "alpha": (1.21, 41.8), "theta": (-0.867, 6.78)}}
THESIS_GAMMA_CRITERION = 24400.0
SCALE = {"xc": (100.0, "cm"), "alpha": (DEG, "deg"), "theta": (DEG, "deg")}


@dataclass
class DipCpxLdfConfig:
    seeds: int = C.field(1000, C.positive, doc="Monte Carlo seeds per estimator")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    variant: str = C.field("printed", C.one_of("printed", "lagrangian"), doc="DIP equations of motion")
    dt: float = C.field(0.001, C.positive_finite, doc="control period (s)")
    substeps: int = C.field(10, C.positive, doc="RK4 sub-steps per period")
    duration: float = C.field(6.5, C.positive_finite, doc="simulated time (s), Table 1's 6.5 s interval")
    Q: list[float] | list[list[float]] = C.field(
        [80.0, 100.0, 300.0, 0.0, 0.0, 0.0],
        doc="PS state weight on [xc, alpha, theta, velocities] (paper: diag(80,300,100,0,0,0) on [xc, theta, alpha])")
    R: float = C.field(0.5, C.positive_finite, doc="PS input weight")
    cpx_gamma: float = C.field(150.0, C.positive_finite, doc="CPX proximal weight gamma")
    cpx_output: str = C.field("prediction", C.one_of("prediction", "current"),
                              doc="what CPX hands the controller: model prediction x~_{k+1} or estimate x^_k")
    ldf_cart_cutoff: float = C.field(100 * math.pi, C.positive_finite, doc="LDF cut-off for xc (rad/s)")
    ldf_angle_cutoff: float = C.field(20 * math.pi, C.positive_finite, doc="LDF cut-off for the angles (rad/s)")
    ldf_zeta: float = C.field(0.9, C.positive_finite, doc="LDF damping ratio")
    encoder_quanta: list[float] = C.field(
        list(dip_sensors.DEFAULT_QUANTA), C.nonneg_finite, C.length(3),
        doc="encoder resolution of xc (m), alpha, theta (rad); Quanser IP02/DIP manuals, not the seeds")
    noise_counts: float = C.field(0.5, C.nonneg_finite, doc="white measurement noise std, in encoder counts")
    input_offset_std: float = C.field(0.0, C.nonneg_finite, doc="per-trial constant input offset std (V)")
    input_noise_std: float = C.field(1.0, C.nonneg_finite, doc="white input disturbance std per period (V)")
    init_radius: float = C.field(0.01, C.nonneg_finite, doc="initial states uniform in this ball around upright")
    state_bound: list[float] = C.field([0.5, 0.7854, 0.7854, INF, INF, INF], C.positive, C.length(6),
                                       doc="|x_i| above this counts as divergence")
    stabilized_tol: float = C.field(0.02, C.positive_finite,
                                    doc="stabilised: max |alpha|, |theta| over the last second below this (rad)")
    sweep_points: int = C.field(11, C.positive, doc="gamma sweep: number of log-spaced points")
    sweep_min: float = C.field(1.0, C.positive_finite, doc="gamma sweep: smallest gamma")
    sweep_max: float = C.field(1e5, C.positive_finite, doc="gamma sweep: largest gamma")
    sweep_seeds: int = C.field(100, C.positive, doc="gamma sweep: seeds per gamma")
    figure_seed: int = C.field(0, C.nonneg, doc="seed of the trial shown in the velocity-estimate figure")

    def loads(self) -> list[Load]:
        n = steps_of(self.duration, self.dt)
        return [Load("the Monte Carlo", ("seeds", "duration"), self.seeds, n),
                Load("the gamma sweep", ("sweep_seeds", "duration"), self.sweep_seeds, n),
                Load("the velocity-estimate trial", ("duration",), 1, n, saved=80 * n)]

    def validate(self):
        weight_matrix("Q", self.Q, 6)
        if self.duration < self.dt:
            raise C.ConfigError("duration", f"must be at least one period (dt = {self.dt})")
        if self.sweep_max < self.sweep_min:
            raise C.ConfigError("sweep_max", "must be at least sweep_min")


# ---- construction -------------------------------------------------------------------------------------------


def build(cfg: DipCpxLdfConfig):
    """Loops and parameters for both estimators, the initial-state sampler, n_steps, and the CPX model."""
    plant = dip.make(cfg.variant)
    p = plant.default_params()
    A, B = linearize(plant.f, p, jnp.zeros(6), jnp.zeros(1))
    model = zoh(A, B, cfg.dt)
    Cmat = dip_sensors.output_matrix(plant.state_names)
    n_steps = int(round(cfg.duration / cfg.dt))
    common = dict(plant=plant, dt=cfg.dt, sensor=dip_sensors.encoder_sensor(cfg.dt),
                  controller=power_series_controller(plant), actuator=input_disturbance(), substeps=cfg.substeps,
                  tail_steps=min(n_steps, int(round(1.0 / cfg.dt))))
    loops = {"cpx": Loop(estimator=cpx_qr(output=cfg.cpx_output), **common),
             "ldf": Loop(estimator=ldf(3, cfg.dt), **common)}
    base = dict(plant=p,
                sensor=dip_sensors.encoder_params(plant.state_names, cfg.encoder_quanta, cfg.noise_counts),
                controller=ps_params(plant, p, weight_matrix("Q", cfg.Q, 6), cfg.R),
                actuator=input_disturbance_params(cfg.input_offset_std, cfg.input_noise_std),
                state_bound=jnp.asarray(cfg.state_bound))
    params = {"cpx": LoopParams(estimator=cpx_params(cfg.cpx_gamma, model, Cmat), **base),
              "ldf": LoopParams(estimator=dip_ldf_params(cfg.ldf_cart_cutoff, cfg.ldf_angle_cutoff, cfg.ldf_zeta),
                                **base)}
    return loops, params, ball_sampler(jnp.zeros(6), cfg.init_radius), n_steps, (model, Cmat)


def cpx_params(gamma, model, Cmat) -> CPXParams:
    return CPXParams(jnp.asarray(gamma, dtype=jnp.float64), model, Cmat, jnp.zeros(6))


def gamma_criterion(cfg: DipCpxLdfConfig) -> dict:
    """Prop. 1.4.3 for CPX on this model at this period (``jaxdip.theory.mhe.cpx_gamma_criterion``)."""
    plant = dip.make(cfg.variant)
    A, B = linearize(plant.f, plant.default_params(), jnp.zeros(6), jnp.zeros(1))
    model = zoh(A, B, cfg.dt)
    g, K, lam = cpx_gamma_criterion(model.Phi, model.Phi_inv, dip_sensors.output_matrix(plant.state_names))
    return {"gamma": float(g), "K_max": float(K), "lambda_min": float(lam), "thesis": THESIS_GAMMA_CRITERION}


# ---- statistics ---------------------------------------------------------------------------------------------


def summarize(cfg, res) -> dict:
    """Table 1's quantities per estimator: seed means of per-trial signed means and variances (cm, deg)."""
    s = trajectory_summary(res, dip.STATE_NAMES, (1, 2), cfg.stabilized_tol)
    st = jax.tree_util.tree_map(np.asarray, res.carry.stats)
    ok = ~np.asarray(res.carry.diverged)
    cnt = np.maximum(st.count, 1)[:, None]
    tmean = st.sum_x / cnt
    rms_err = np.sqrt(st.sum_err2 / cnt)
    out = {"diverged": s["diverged"], "stabilized_fraction": s["stabilized_fraction"],
           "stabilized_fraction_ci95": s["stabilized_fraction_ci95"]}
    for name in ("xc", "alpha", "theta"):
        k, unit = SCALE[name]
        i = dip.STATE_NAMES.index(name)
        m, mci = s["states"][name]["mean"], s["states"][name]["mean_ci95"]
        v, vci = s["states"][name]["var"], s["states"][name]["var_ci95"]
        out[f"{name}_mean_{unit}"] = k * m
        out[f"{name}_mean_{unit}_ci95"] = [k * c for c in mci]
        out[f"{name}_var"] = k**2 * v
        out[f"{name}_var_ci95"] = [k**2 * c for c in vci]
        out.update({f"{name}_abs_trial_mean_{unit}" if kk == "a" else f"{name}_abs_trial_mean_{unit}_ci95": val
                    for kk, val in zip(("a", "c"), _scaled(stats.mean_ci(np.abs(tmean[:, i]), ok), k))})
    for name in ("xc_dot", "alpha_dot", "theta_dot"):
        i = dip.STATE_NAMES.index(name)
        m, ci = stats.mean_ci(rms_err[:, i], ok)
        out[f"{name}_rms_err"], out[f"{name}_rms_err_ci95"] = m, ci
    u_var = s["u"]["var"]
    out["u_var"], out["u_var_ci95"] = u_var, s["u"]["var_ci95"]
    return out


def _scaled(mci, k):
    m, ci = mci
    return k * m, [k * c for c in ci]


# ---- the gamma sweep: one compiled loop, gamma a params leaf ------------------------------------------------


def make_batch_fn(loop: Loop, x0_fn, n_steps: int):
    """jit(vmap over seeds) of a whole trajectory's statistics; params are an argument, so new gammas reuse it."""

    def one(params, base_key, i):
        sk = montecarlo.seed_key(base_key, i)
        carry = init_carry(loop, params, x0_fn(jax.random.fold_in(sk, 0)), sk)
        carry, _ = advance(loop, n_steps, params, sk, carry, n_steps)
        return carry

    return jax.jit(jax.vmap(one, in_axes=(None, None, 0)))


def gamma_sweep(cfg, loop, params, x0_fn, n_steps, progress=True) -> dict:
    gammas = np.geomspace(cfg.sweep_min, cfg.sweep_max, cfg.sweep_points)
    fn = make_batch_fn(loop, x0_fn, n_steps)
    seeds = np.arange(cfg.sweep_seeds, dtype=np.uint32)
    seeds_arr = jnp.asarray(seeds)
    n_dev = jax.device_count()
    if n_dev > 1 and cfg.sweep_seeds % n_dev == 0:
        from jax.sharding import NamedSharding, PartitionSpec

        seeds_arr = jax.device_put(seeds_arr, NamedSharding(montecarlo.device_mesh(), PartitionSpec("seeds")))
    i_th, i_thd = dip.STATE_NAMES.index("theta"), dip.STATE_NAMES.index("theta_dot")
    out = {"gamma": gammas.tolist(), "seeds": cfg.sweep_seeds, "theta_var": [], "theta_var_ci95": [],
           "theta_dot_rms_err": [], "diverged_fraction": [], "diverged_fraction_ci95": []}
    bar = Progress(len(gammas), desc="dip-cpx-ldf gamma sweep", enabled=progress)
    key = jax.random.PRNGKey(cfg.seed)
    for g in gammas:
        p = params._replace(estimator=params.estimator._replace(gamma=jnp.asarray(g, dtype=jnp.float64)))
        carry = jax.tree_util.tree_map(np.asarray, fn(p, key, seeds_arr))
        st, div = carry.stats, carry.diverged
        ok = ~div
        cnt = np.maximum(st.count, 1)
        var = DEG**2 * (st.sum_x2[:, i_th] / cnt - (st.sum_x[:, i_th] / cnt) ** 2)
        m, ci = stats.mean_ci(var, ok)
        e, _ = stats.mean_ci(np.sqrt(st.sum_err2[:, i_thd] / cnt), ok)
        f, fci = stats.wilson(int(div.sum()), len(div))
        out["theta_var"].append(m)
        out["theta_var_ci95"].append(ci)
        out["theta_dot_rms_err"].append(e)
        out["diverged_fraction"].append(f)
        out["diverged_fraction_ci95"].append(fci)
        bar.update(1, postfix=f"gamma={g:.3g} div={f:.2f}")
    bar.close()
    return out


# ---- one trial's velocity estimates (thesis Fig. 3.5) ------------------------------------------------------


def velocity_trial(cfg, loop, params, x0_fn, n_steps, model, Cmat, gamma_crit):
    """One CPX-controlled trial; on its measurements, offline: LDF, CPX at cfg.cpx_gamma and at the criterion."""
    sk = montecarlo.seed_key(jax.random.PRNGKey(cfg.seed), cfg.figure_seed)
    x0 = x0_fn(jax.random.fold_in(sk, 0))
    carry, rec = jax.jit(lambda q: rollout(loop, q, x0, sk, n_steps, 1))(params)
    ys, us = rec.y, rec.u
    us_prev = jnp.concatenate([jnp.zeros_like(us[:1]), us[:-1]])
    est_ldf = filter_sequence(ldf(3, cfg.dt), params_ldf(cfg), ys, us_prev, x0)[1]
    cur = cpx_qr(output="current")
    est_cpx = filter_sequence(cur, cpx_params(cfg.cpx_gamma, model, Cmat), ys, us_prev, x0)[1]
    est_crit = filter_sequence(cur, cpx_params(gamma_crit, model, Cmat), ys, us_prev, x0)[1]
    return {"x": np.asarray(rec.x), "ldf": np.asarray(est_ldf), "cpx": np.asarray(est_cpx),
            "cpx_crit": np.asarray(est_crit), "diverged": bool(carry.diverged)}


def params_ldf(cfg):
    return dip_ldf_params(cfg.ldf_cart_cutoff, cfg.ldf_angle_cutoff, cfg.ldf_zeta)


def velocity_figure(cfg, tr, gamma_crit):
    import matplotlib.pyplot as plt

    i = dip.STATE_NAMES.index("theta_dot")
    t = np.arange(tr["x"].shape[0]) * cfg.dt
    win = t <= min(1.0, t[-1])
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax = axes[0]
    ax.plot(t[win], tr["ldf"][win, i], lw=0.9, label="LDF")
    ax.plot(t[win], tr["cpx"][win, i], lw=0.9, label=f"CPX, gamma = {cfg.cpx_gamma:g}")
    ax.plot(t[win], tr["x"][win, i], "k", lw=1.2, label="truth")
    ax.set_ylabel("theta_dot (rad/s)")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title("one CPX-controlled trial: estimates of theta_dot from the same encoder readings (cf. Fig. 3.5)")
    ax = axes[1]
    ax.plot(t[win], tr["cpx_crit"][win, i], lw=0.7, color="C3", label=f"CPX, gamma = {gamma_crit:.0f} (criterion)")
    ax.plot(t[win], tr["x"][win, i], "k", lw=1.2, label="truth")
    ax.set_ylabel("theta_dot (rad/s)")
    ax.set_xlabel("time (s)")
    ax.legend(fontsize=8, loc="upper right")
    for a in axes:
        a.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def sweep_figure(cfg, sw, gamma_crit):
    import matplotlib.pyplot as plt

    g = np.asarray(sw["gamma"])
    v = np.asarray(sw["theta_var"], dtype=float)
    ci = np.asarray(sw["theta_var_ci95"], dtype=float)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    a1.fill_between(g, ci[:, 0], ci[:, 1], alpha=0.3)
    a1.plot(g, v, "o-", ms=3)
    a1.set_yscale("log")
    a1.set_ylabel("var theta (deg^2), non-diverged")
    a2.plot(g, sw["diverged_fraction"], "o-", ms=3, color="C3")
    a2.set_ylabel("diverged fraction")
    a2.set_ylim(-0.03, 1.03)
    a2.set_xlabel("CPX gamma")
    for a in (a1, a2):
        a.set_xscale("log")
        a.axvline(gamma_crit, color="k", ls="--", lw=1, label=f"Prop. 1.4.3 criterion {gamma_crit:.0f}")
        a.axvline(cfg.cpx_gamma, color="C2", ls=":", lw=1, label=f"paper's gamma {cfg.cpx_gamma:g}")
        a.grid(alpha=0.3, which="both")
    a1.legend(fontsize=8)
    a1.set_title(f"CPX gamma sweep: {sw['seeds']} seeds per gamma, {cfg.duration} s")
    fig.tight_layout()
    return fig


# ---- run and report -----------------------------------------------------------------------------------------


def run(cfg: DipCpxLdfConfig, ctx: RunContext | None = None, progress: bool = True) -> Outcome:
    loops, params, x0_fn, n_steps, (model, Cmat) = build(cfg)
    crit = gamma_criterion(cfg)
    results = {}
    for name in ("cpx", "ldf"):
        res = montecarlo.run(loops[name], params[name], x0_fn, jax.random.PRNGKey(cfg.seed), cfg.seeds, n_steps,
                             shard=jax.device_count() > 1 and cfg.seeds >= 512, progress=progress,
                             desc=f"dip-cpx-ldf {name}")
        results[name] = summarize(cfg, res)
    results["gamma_criterion"] = crit
    results["gamma_sweep"] = gamma_sweep(cfg, loops["cpx"], params["cpx"], x0_fn, n_steps, progress)
    tr = velocity_trial(cfg, loops["cpx"], params["cpx"], x0_fn, n_steps, model, Cmat, crit["gamma"])
    i = dip.STATE_NAMES.index("theta_dot")
    rms = lambda e: float(np.sqrt(np.mean((e[:, i] - tr["x"][:, i]) ** 2)))
    results["velocity_trial"] = {"seed": cfg.figure_seed, "diverged": tr["diverged"],
                                 "theta_dot_rms_err_ldf": rms(tr["ldf"]), "theta_dot_rms_err_cpx": rms(tr["cpx"]),
                                 "theta_dot_rms_err_cpx_criterion": rms(tr["cpx_crit"])}
    figures = {"gamma_sweep": sweep_figure(cfg, results["gamma_sweep"], crit["gamma"]),
               "velocity_estimates": velocity_figure(cfg, tr, crit["gamma"])}
    return Outcome(results=results, report=report(cfg, results), figures=figures)


def _row(label, r):
    cells = []
    for name in ("xc", "alpha", "theta"):
        unit = SCALE[name][1]
        cells += [fmt_ci(r[f"{name}_mean_{unit}"], r[f"{name}_mean_{unit}_ci95"], 3),
                  fmt_ci(r[f"{name}_abs_trial_mean_{unit}"], r[f"{name}_abs_trial_mean_{unit}_ci95"], 3),
                  fmt_ci(r[f"{name}_var"], r[f"{name}_var_ci95"], 3)]
    return f"| {label} | " + " | ".join(cells) + f" | {r['diverged']} |"


def report(cfg, r) -> str:
    crit = r["gamma_criterion"]
    sw = r["gamma_sweep"]
    c, l = r["cpx"], r["ldf"]
    lines = [
        f"Printed DIP model, power-series control (3.5), Q = {cfg.Q} on [xc, alpha, theta, velocities], "
        f"R = {cfg.R}; {cfg.seeds} seeds per estimator, {cfg.duration} s at {1 / cfg.dt:g} Hz, initial states "
        f"uniform in a ball of radius {cfg.init_radius} around upright. Encoders xc/alpha/theta quantised to "
        f"{cfg.encoder_quanta} (m, rad, rad; Quanser's 4096 counts/rev, not from the documents) with white noise "
        f"of {cfg.noise_counts} count; input disturbance: per-trial offset std {cfg.input_offset_std} V and white "
        f"noise std {cfg.input_noise_std} V per period. CPX: gamma = {cfg.cpx_gamma:g}, hands the controller its "
        f"{cfg.cpx_output}; LDF: cut-offs {cfg.ldf_cart_cutoff:.4g} / {cfg.ldf_angle_cutoff:.4g} rad/s, "
        f"damping {cfg.ldf_zeta}.",
        "",
        "Per-trial signed time mean, |time mean| and time variance, averaged over the non-diverged seeds (95% "
        "intervals); xc in cm (variance cm^2), angles in degrees (variance deg^2):",
        "",
        "| estimator | xc mean | xc abs mean | xc var | alpha mean | alpha abs mean | alpha var | theta mean | "
        "theta abs mean | theta var | diverged |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        _row("CPX", c),
        _row("LDF", l),
    ]
    for k in ("cpx", "ldf"):
        t = TABLE_1[k]
        lines.append(f"| {k.upper()} (paper, lab, one run) | {t['xc'][0]} | | {t['xc'][1]} | {t['alpha'][0]} | | "
                     f"{t['alpha'][1]} | {t['theta'][0]} | | {t['theta'][1]} | |")
    lines += [
        "",
        "RMS error of the velocity estimates handed to the controller (rad/s, m/s): "
        + "; ".join(f"{k.upper()}: " + ", ".join(f"{n} {r[k][f'{n}_rms_err']:.3g}"
                                               for n in ("xc_dot", "alpha_dot", "theta_dot")) for k in ("cpx", "ldf"))
        + ".",
        "",
        f"Closer to upright with CPX than with the LDF (seed-mean |trial mean| of xc, alpha, theta all smaller): "
        f"{'yes' if _closer(c, l) else 'no'}; less variance with CPX (all three variances smaller): "
        f"{'yes' if _less_var(c, l) else 'no'}.",
        "",
        "## The gamma criterion and the sweep",
        "",
        f"Prop. 1.4.3 for CPX on this model at {cfg.dt * 1e3:g} ms: gamma > {crit['gamma']:.1f} "
        f"(||Phi|| = {crit['K_max']:.6f}, lambda_min(G^T G) = {crit['lambda_min']:.4e}); the thesis gives "
        f"{THESIS_GAMMA_CRITERION:g}.",
        "",
        "| gamma | var theta (deg^2) | theta_dot rms err (rad/s) | diverged fraction |",
        "|---|---|---|---|",
    ]
    for g, v, vci, e, f in zip(sw["gamma"], sw["theta_var"], sw["theta_var_ci95"], sw["theta_dot_rms_err"],
                               sw["diverged_fraction"]):
        lines.append(f"| {g:.4g} | {fmt_ci(v, vci, 3)} | {e:.3g} | {f:.3f} |")
    vt = r["velocity_trial"]
    lines += [
        "",
        f"One trial (seed {vt['seed']}), estimates from the same readings: RMS error of theta_dot LDF "
        f"{vt['theta_dot_rms_err_ldf']:.3g}, CPX at gamma = {cfg.cpx_gamma:g} {vt['theta_dot_rms_err_cpx']:.3g}, "
        f"CPX at the criterion's gamma {vt['theta_dot_rms_err_cpx_criterion']:.3g} rad/s.",
    ]
    return "\n".join(lines)


def _closer(c, l):
    return all(c[f"{n}_abs_trial_mean_{SCALE[n][1]}"] < l[f"{n}_abs_trial_mean_{SCALE[n][1]}"]
               for n in ("xc", "alpha", "theta"))


def _less_var(c, l):
    return all(c[f"{n}_var"] < l[f"{n}_var"] for n in ("xc", "alpha", "theta"))


EXPERIMENT = register(Experiment(
    id="dip-cpx-ldf",
    title="DIP: power-series control fed by CPX vs the low-pass derivative filter",
    config_cls=DipCpxLdfConfig,
    run=run,
    quick={"seeds": 16, "duration": 1.0, "sweep_points": 5, "sweep_seeds": 8},
    source="paper §5 Table 1 / thesis §3.3 Table 3.2, Fig. 3.5, the Prop. 1.4.3 gamma criterion",
))
