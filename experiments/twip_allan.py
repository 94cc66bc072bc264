"""twip-allan: the Allan deviation of the simulated TWIP sensors against Table 7.1's law (Stumfoll Fig. 7.1).

Fig. 7.1 compares the Allan variance of the robot's measured gyro data with simulated data; the measured data are
not printed, so what a run can check is that the library's sensors (``TwipSensors.table_7_1`` at rest, walking
biases started stationary, complementary filter off so the tilt channel is the accelerometer's own angle) have
the Allan deviation that Table 7.1 implies under the library's reading (``jaxdip.sim.twip_sensors.table_7_1``):
white noise of variance sigma_r^2 per sample plus the Gauss-Markov bias (155) driven at intensity sigma_br^2.
The law compared with is the exact one of the samples (``jaxdip.sim.allan.avar_sampled_white_gauss_markov``).
Beside it, the encoder's errors (position quantum, velocity by difference) on a robot driving slowly.

A supporting run of the fidelity readings (docs/fidelity/twip.md): not part of a plain ``jaxdip reproduce``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip import config as C
from jaxdip.runner.experiment import Experiment, Outcome, RunContext
from jaxdip.runner.per_seed import PerSeed, order_of

SENSORS = ("tilt", "gyro")
HOLD_FRACTION = 0.8  # a sensor holds when the law lies inside our interval at this fraction of the cluster times
SHORT_TAU_S = 100.0  # the largest deviation is also reported over tau <= this, where the records are long enough


@dataclass
class TwipAllanConfig:
    records: int = C.field(8, C.positive, doc="independent sensor records (the interval comes from their spread)")
    hours: float = C.field(4.0, C.positive_finite, doc="length of each record (h)")
    dt: float = C.field(0.01, C.positive_finite, doc="sampling period (s)")
    clusters: int = C.field(14, C.positive, doc="cluster times, log-spaced from dt to a tenth of a record "
                            "(duplicates after rounding to whole samples are dropped)")
    seed: int = C.field(100, C.nonneg, doc="record i uses the PRNG key seed + i")
    encoder_duration: float = C.field(200.0, C.positive_finite, doc="encoder check: time driven at ~0.1 m/s (s)")

    @property
    def seeds(self) -> int:  # the header's and metrics.json's seed count
        return self.records

    def samples(self) -> int:
        return int(self.hours * 3600 / self.dt)

    def validate(self):
        if self.records < 2:
            raise C.ConfigError("records", "must be at least 2 (the interval comes from their spread)")
        if self.samples() < 100:
            raise C.ConfigError("hours", f"a record must hold at least 100 samples of dt = {self.dt} s")
        if self.samples() > 10**8:
            raise C.ConfigError("hours", f"{self.samples()} samples per record is more than 1e8: shorten it")
        if self.clusters < 2:
            raise C.ConfigError("clusters", "must be at least 2")
        if int(round(self.encoder_duration / self.dt)) < 10:
            raise C.ConfigError("encoder_duration", f"must be at least 10 periods (dt = {self.dt})")


def cluster_sizes(n: int, clusters: int) -> np.ndarray:
    """Cluster sizes m (samples), log-spaced from 1 to n / 10, rounded and deduplicated."""
    return np.unique(np.round(np.logspace(0, math.log10(n / 10), clusters)).astype(int))


class AtRest(jd.DiscretePlant):
    """The TWIP held still: its state never changes (the sensors' records at rest)."""

    state_names = ("x", "x_dot", "phi", "phi_dot")

    def step(self, x, u):
        return x


def records(cfg: TwipAllanConfig):
    """The (samples, 2) records [tilt, gyro] of the sensors at rest, one per key seed + i (a generator): the
    engine's loop with the robot held still, its measurements saved every period."""
    from jaxdip.sim.twip_sensors import TwipSensors

    # cf_alpha = 0: the tilt channel is the accelerometer's own angle; stationary biases: a long record's law
    sens = TwipSensors.table_7_1(cfg.dt, cf_alpha=0.0, stationary_start=True)
    loop = jd.Loop(plant=AtRest(), sensor=sens, estimator=jd.Passthrough(),
                   controller=jd.control.ConstantInput(jnp.zeros(1)), dt=cfg.dt, substeps=1)
    record = jax.jit(lambda key: jd.simulate(loop, jnp.zeros(4), key, cfg.samples(), save=lambda s: s.y[2:]).saved)
    for i in range(cfg.records):
        yield np.asarray(record(jax.random.PRNGKey(cfg.seed + i)))


class Driving(jd.DiscretePlant):
    """The TWIP driving at about 0.1 m/s, x(t) = 0.1 t + 0.02 sin(w t), on an exact discrete path: the tilt
    slots carry (sin w t, cos w t), rotated by w dt every period (the encoder check reads only x and x_dot)."""

    dt: float = eqx.field(static=True)
    w: float = eqx.field(static=True, default=0.7)
    state_names = ("x", "x_dot", "phi", "phi_dot")

    def step(self, x, u):
        c, s = math.cos(self.w * self.dt), math.sin(self.w * self.dt)
        sn, cn = x[2] * c + x[3] * s, x[3] * c - x[2] * s
        return jnp.stack([x[0] + 0.1 * self.dt + 0.02 * (sn - x[2]), 0.1 + 0.02 * self.w * cn, sn, cn])


def encoder_check(cfg: TwipAllanConfig) -> dict:
    """Position error and velocity grid of the simulated encoder on a robot driving at about 0.1 m/s."""
    from jaxdip.sim.twip_sensors import TwipSensors, table_7_1

    q = table_7_1()["encoder_quantum"]
    n = int(round(cfg.encoder_duration / cfg.dt))
    loop = jd.Loop(plant=Driving(cfg.dt), sensor=TwipSensors.table_7_1(cfg.dt, cf_alpha=0.0),
                   estimator=jd.Passthrough(), controller=jd.control.ConstantInput(jnp.zeros(1)), dt=cfg.dt,
                   substeps=1)
    x0 = jnp.array([0.0, 0.1 + 0.02 * 0.7, 0.0, 1.0])
    sol = jd.simulate(loop, x0, jax.random.PRNGKey(0), n, save=lambda s: (s.x[:2], s.y[:2]))
    xs, ys = (np.asarray(a) for a in sol.saved)
    tt = np.arange(n) * cfg.dt
    perr = float(np.max(np.abs(ys[:, 0] - xs[:, 0])))
    vstep = float(np.min(np.diff(np.unique(np.round(ys[1:, 1], 12)))))
    ok = perr <= q / 2 + 1e-12 and abs(vstep - q / cfg.dt) < 1e-9 * q / cfg.dt
    return {"quantum_m": q, "velocity_quantum_m_s": q / cfg.dt, "duration_s": float(tt[-1]),
            "max_position_error_m": perr, "velocity_step_m_s": vstep, "holds": bool(ok)}


def compute(cfg: TwipAllanConfig) -> tuple[dict, PerSeed]:
    from scipy.stats import t as t_dist

    from jaxdip.sim import allan as A
    from jaxdip.sim.twip_sensors import DEG, table_7_1

    ms = cluster_sizes(cfg.samples(), cfg.clusters)
    taus = ms * cfg.dt
    av = {s: [] for s in SENSORS}
    for y in records(cfg):
        for j, s in enumerate(SENSORS):
            av[s].append(A.allan_variance(y[:, j], ms))
    tab = table_7_1()
    out = {"tau_s": taus.tolist(), "cluster_samples": ms.tolist(), "record_hours": cfg.hours,
           "records": cfg.records}
    for s in SENSORS:
        law = A.avar_sampled_white_gauss_markov(tab[f"{s}_white_std"] ** 2, tab[f"{s}_gm_sigma"] ** 2,
                                                tab[f"{s}_gm_tau"], cfg.dt, ms)
        a = np.array(av[s])
        mean = a.mean(0)
        # Student's t: the interval comes from only `records` values
        half = t_dist.ppf(0.975, cfg.records - 1) * a.std(0, ddof=1) / math.sqrt(cfg.records)
        lo, hi = np.maximum(mean - half, 0.0), mean + half
        inside = (lo <= law) & (law <= hi)
        dev = np.abs(np.sqrt(mean / law) - 1)
        short = taus <= SHORT_TAU_S
        # in degrees (deg or deg/s) like Fig. 7.1
        out[s] = {"unit": "deg" if s == "tilt" else "deg/s",
                  "adev": (np.sqrt(mean) / DEG).tolist(),
                  "adev_ci95": (np.stack([np.sqrt(lo), np.sqrt(hi)], 1) / DEG).tolist(),
                  "law_adev": (np.sqrt(law) / DEG).tolist(), "law_inside": inside.tolist(),
                  "held": int(inside.sum()), "clusters": len(ms),
                  "max_deviation_short": float(np.max(dev[short])) if short.any() else float(np.max(dev)),
                  "max_deviation": float(np.max(dev)),
                  "holds": bool(inside.mean() >= HOLD_FRACTION)}
    out["encoder"] = encoder_check(cfg)
    data = PerSeed(coords={"sensor": list(SENSORS), "tau_index": np.arange(len(ms)), "tau": ("tau_index", taus)})
    data.add("allan_variance", ("record_seed", "sensor", "tau_index"),
             np.stack([np.array(av[s]) for s in SENSORS], 1) / DEG**2, "deg^2 (tilt) or (deg/s)^2 (gyro)",
             "the record's Allan variance at each cluster time (record i: key seed + i)",
             **order_of("{sensor}.adev.{tau_index}", "root_mean"))
    return out, data


def _g(v, d=4) -> str:
    return f"{v:.{d}g}"


def report(cfg: TwipAllanConfig, r: dict) -> str:
    L = [f"Allan deviation of the simulated sensors at rest (walking biases started stationary, dt = {cfg.dt} s), "
         f"{cfg.records} records of {cfg.hours:g} h each; ours = mean of the overlapping Allan variances over the "
         f"records, 95% interval from their spread (Student's t, {cfg.records - 1} degrees of freedom). Law: Table "
         "7.1 read as a per-sample white variance sigma_r^2 plus the Gauss-Markov bias (155) of intensity "
         "sigma_br^2 and time constant tau_r (for tau >> dt: ADEV^2 = sigma_r^2 dt / tau + sigma_br^2 tau_r^2 / "
         "tau [1 - tau_r / (2 tau) (3 - 4 e^(-tau/tau_r) + e^(-2 tau/tau_r))]), exact for the samples. A cluster "
         "time holds where the law lies inside our interval; a sensor holds when at least "
         f"{100 * HOLD_FRACTION:.0f}% do.", "",
         "| sensor | tau (s) | ADEV ours | ADEV from Table 7.1 (exact, sampled) | holds |", "|---|---|---|---|---|"]
    for s in SENSORS:
        e, u = r[s], r[s]["unit"]
        for j, tau in enumerate(r["tau_s"]):
            lo, hi = e["adev_ci95"][j]
            L.append(f"| {s} | {tau:.3g} | {_g(e['adev'][j])} [{_g(lo)}, {_g(hi)}] {u} | {_g(e['law_adev'][j])} "
                     f"{u} | {'yes' if e['law_inside'][j] else 'no'} |")
        L.append(f"| {s} | | {e['held']}/{e['clusters']} cluster times hold; largest deviation of ADEV "
                 f"{100 * e['max_deviation_short']:.2f}% for tau <= {SHORT_TAU_S:g} s | | "
                 f"{'yes' if e['holds'] else 'no'} (>= {100 * HOLD_FRACTION:.0f}% hold) |")
    enc = r["encoder"]
    L += ["", f"Encoder (Table 7.1: position error {enc['quantum_m']} m, velocity {enc['quantum_m']}/dt m/s), on a "
          f"robot driving at about 0.1 m/s for {enc['duration_s']:.0f} s: largest |position error| "
          f"{enc['max_position_error_m']:.3g} m (half a quantum is {enc['quantum_m'] / 2:.3g} m), velocity readings "
          f"on a grid of {_g(enc['velocity_step_m_s'])} m/s (q/dt = {enc['velocity_quantum_m_s']:.4g} m/s): "
          f"{'holds' if enc['holds'] else 'does not hold'}."]
    return "\n".join(L)


def figure(r: dict):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    tau = np.asarray(r["tau_s"])
    for ax, s in zip(axes, SENSORS):
        e = r[s]
        m, ci = np.asarray(e["adev"]), np.asarray(e["adev_ci95"])
        ax.errorbar(tau, m, yerr=[m - ci[:, 0], ci[:, 1] - m], fmt="o", ms=3, capsize=2,
                    label=f"simulated ({r['records']} x {r['record_hours']:g} h, 95%)")
        ax.loglog(tau, e["law_adev"], "k-", lw=1, label="Table 7.1 law")
        ax.set_xlabel("tau (s)")
        ax.set_ylabel(f"Allan deviation ({e['unit']})")
        ax.set_title(f"{s}: Fig. 7.1 analogue")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    return fig


def run(cfg: TwipAllanConfig, ctx: RunContext | None = None) -> Outcome:
    r, data = compute(cfg)
    return Outcome(results=r, report=report(cfg, r), figures={"allan_deviation": figure(r)}, per_seed=data)


EXPERIMENT = Experiment(
    id="twip-allan",
    title="Allan deviation of the simulated TWIP sensors against Table 7.1 (fidelity readings)",
    config_cls=TwipAllanConfig,
    run=run,
    quick={"records": 2, "hours": 0.25},
    source="Stumfoll Fig. 7.1 / Table 7.1",
    reproduce=False,
)
