"""tune: gradient-based tuning of estimator and controller hyperparameters (``jaxdip.tune``).

For a target (``--set target=...``: ``cpx``, ``rwp``, ``dmso``, ``rp``, ``extra``) the experiment tunes the
hyperparameters on one set of seeds by gradient (optax Adam on log-parameters, forward-mode derivatives through
the whole closed loop), evaluates them on a disjoint held-out set of seeds, and compares with the documents'
values and with a random search given the same number of closed-loop simulations (also converted to
evaluation-equivalents with the measured cost of a gradient step).

cpx: gamma of CPX on the DIP stabilisation task of ``dip-cpx-ldf`` (the scenario ``jaxdip.scenarios.dip_cpx_ldf``);
loss per seed = time variance of alpha plus that of theta (deg^2) + ``divergence_penalty`` if it diverged.
The encoders quantise, so one sample path's loss is piecewise constant in gamma with jumps (finite differences
of it measure the jumps); ``smoothing = "straight_through"`` differentiates the quantiser as the identity
(``jaxdip.tune.straight_through_sensor``), ``"none"`` uses the exact pathwise derivative (round' = 0).

rwp, dmso, rp, extra: see ``RWPTarget``, ``DMSOTarget`` (Gamma and diag K_MSO on the noisy TWIP case of
``twip-dmso``; ``smoothing`` picks that experiment's ``encoder_gradient``), ``RPTarget`` (gamma of (2.14) on the
DIP with a fixed LQR-derived P), ``ExtraTarget`` (k1, k2 and the four learning rates of the TWIP extra control on
the ``unmodeled`` case, Table 8.3's score); ``smoothing`` does not apply to rp and extra: no quantiser.

Held-out scenarios. The tuning seeds run the target's nominal scenario; every held-out seed draws its own
(``ScenarioDraw``): the initial state, the constant sensor bias and the disturbance's size are each scaled by
1 + U(-s, s) with s = ``heldout_x0_spread``, ``heldout_bias_spread``, ``heldout_disturbance_spread`` (default
0.5 each; 0 everywhere gives the tuning scenario with new noise only, the behaviour before these keys). Which
leaves each kind scales is the target's ``scenario_leaves``; a kind a target lacks is not drawn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

import jaxdip as jd
from jaxdip import checkpoint as ckpt
from jaxdip import config as C
from jaxdip import stats
from jaxdip.engine import effort
from jaxdip.experiments.base import Experiment, Outcome, RunContext
from jaxdip.experiments.common import fmt_ci
from jaxdip.resources import Load, steps_of
from jaxdip.tune import Bounded, Log, Objective, random_search, tune

IMPLEMENTED = ("cpx", "rwp", "dmso", "rp", "extra")
HELDOUT_OFFSET = 1_000_000  # held-out seed i is base seed HELDOUT_OFFSET + i; tuning seeds are 0 .. seeds-1
# the held-out scenario of seed i is drawn from fold_in(key_i, SCENARIO_TAG): a stream none of the trial's own
# draws uses (they take fold_in(key_i, 0) and splits of key_i), so a seed's noise is the same with or without
# scenario variation, and the paper's, tuned and random-search values meet the same scenarios (paired)
SCENARIO_TAG = 0x5CE9A410
SCENARIO_KINDS = ("x0", "bias", "disturbance")


@dataclass
class TuneConfig:
    target: str = C.field("cpx", doc=f"what to tune: one of {', '.join(IMPLEMENTED)}")
    seeds: int = C.field(32, C.positive, doc="tuning seeds (common to every optimiser step with crn = true)")
    heldout_seeds: int = C.field(256, C.positive, doc="held-out evaluation seeds, disjoint from the tuning seeds")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    duration: float = C.field(2.0, C.positive_finite, doc="simulated time per closed loop (s)")
    substeps: int = C.field(10, C.positive, doc="RK4 sub-steps per period")
    steps: int = C.field(30, C.positive, doc="optimiser steps (at most)")
    lr: float = C.field(0.3, C.positive_finite,
                        doc="Adam learning rate / Rprop initial step (on the log of each hyperparameter)")
    optimizer: str = C.field("adam", C.one_of("adam", "rprop"),
                             doc="adam (after clipping), or rprop: per-coordinate steps that grow x1.2 while the "
                                 "gradient's sign holds and halve when it flips (clipping does not apply)")
    clip: float = C.field(1.0, C.positive_finite, doc="global-norm gradient clipping")
    crn: bool = C.field(True, doc="common random numbers: the same seeds' noise at every step (false: resample)")
    patience: int = C.field(10, C.nonneg, doc="early stopping after this many steps without improvement (0: off)")
    smoothing: str = C.field("straight_through", C.one_of("straight_through", "none"),
                             doc="derivative of the encoder quantiser: identity (straight-through) or 0 (exact)")
    mode: str = C.field("forward", C.one_of("forward", "reverse"), doc="forward- or reverse-mode derivatives")
    divergence_penalty: float = C.field(1000.0, C.nonneg_finite,
                                        doc="added to a diverged seed's loss (in the target's loss unit; not rp)")
    search_low: float = C.field(1.0, C.positive_finite, doc="random search / landscape: lowest gamma")
    search_high: float = C.field(1e5, C.positive_finite, doc="random search / landscape: highest gamma")
    landscape_points: int = C.field(9, C.positive, doc="points of the loss landscape along gamma")
    search_factor: float = C.field(10.0, C.positive_finite,
                                   doc="rwp, dmso, rp, extra: random search / landscape log-uniform within paper value "
                                       "x/÷ this")
    wheel_weight: float = C.field(1e-3, C.nonneg_finite,
                                  doc="rwp: weight of the integrated squared wheel speed ((rad/s)^2 s) in the loss")
    heldout_x0_spread: float = C.field(
        0.5, C.nonneg_finite,
        doc="held-out seeds: each scales its initial state by (1 + U(-s, s)) per entry (cpx, rp: the radius / std of "
            "the initial-state draw; rwp: theta0; dmso, extra: x0); 0: the tuning scenario")
    heldout_bias_spread: float = C.field(
        0.5, C.nonneg_finite,
        doc="held-out seeds: each scales the constant sensor bias by (1 + U(-s, s)) (rwp: d = -0.08 rad; the other "
            "targets have none)")
    heldout_disturbance_spread: float = C.field(
        0.5, C.nonneg_finite,
        doc="held-out seeds: each scales the disturbance's size by (1 + U(-s, s)) (cpx: the white input "
            "disturbance's std; rp: the state noise's std; extra: the gains of d1, d2 (185); rwp, dmso: none)")

    def loads(self) -> list[Load]:
        n = steps_of(self.duration, 0.001)  # the finest period of the targets (the DIP's 1 ms)
        return [Load("a tuning step", ("seeds", "duration"), self.seeds, n, saved=64 * n),
                Load("the held-out evaluation", ("heldout_seeds", "duration"), self.heldout_seeds, n)]

    def validate(self):
        if self.target not in IMPLEMENTED:
            raise C.ConfigError("target", f"must be one of {', '.join(map(repr, IMPLEMENTED))}")
        if self.search_high <= self.search_low:
            raise C.ConfigError("search_high", "must exceed search_low")
        for kind in SCENARIO_KINDS:
            if getattr(self, f"heldout_{kind}_spread") >= 1.0:  # a factor 1 + U(-s, s) must stay positive
                raise C.ConfigError(f"heldout_{kind}_spread", "must be below 1 (the factor 1 + U(-s, s) keeps its sign)")

    def scenario_spreads(self) -> dict:
        """{kind: spread} of the held-out scenario draw."""
        return {k: getattr(self, f"heldout_{k}_spread") for k in SCENARIO_KINDS}


class ScenarioDraw(eqx.Module):
    """A Monte Carlo trial ``fn(key, *rest)`` whose scenario is drawn per seed: every leaf that a ``where``
    selects is multiplied by 1 + U(-s, s) (independently per entry), from ``fold_in(key, SCENARIO_TAG)``; the
    trial then runs with its own key unchanged."""

    fn: Any
    wheres: tuple = eqx.field(static=True)
    spreads: tuple = eqx.field(static=True)

    def __call__(self, key, *rest):
        ks = jax.random.split(jax.random.fold_in(key, SCENARIO_TAG), len(self.wheres))
        fn = self.fn
        for where, s, k in zip(self.wheres, self.spreads, ks):
            leaf = where(fn)
            fn = eqx.tree_at(where, fn, leaf * scenario_factor(k, s, jnp.shape(leaf)))
        return fn(key, *rest)


def scenario_factor(key, spread: float, shape=()):
    """1 + U(-spread, spread), per entry of ``shape``."""
    return 1.0 + spread * jax.random.uniform(key, shape, minval=-1.0, maxval=1.0)


def with_scenarios(fn, leaves: dict, spreads: Optional[dict]):
    """``fn`` drawing its scenario per seed (``ScenarioDraw``) over the ``leaves`` ({kind: [where, ...]}) whose
    kind has a positive spread; ``fn`` itself when none has (the tuning scenario, unchanged)."""
    pairs = [(w, float(spreads[k])) for k, ws in leaves.items() for w in ws if spreads and spreads.get(k, 0.0) > 0]
    if not pairs:
        return fn
    return ScenarioDraw(fn, tuple(w for w, _ in pairs), tuple(s for _, s in pairs))


# ---- targets ------------------------------------------------------------------------------------------------


class Target:
    """What a target supplies: J(theta, key) on given seeds, the documents' theta, a spec, a sampler."""

    name: str
    param: str  # the parameter drawn in the landscape

    # {kind: [where, ...]}: the leaves of the object that ``objective`` runs through ``monte_carlo`` which a
    # held-out scenario draw scales (``SCENARIO_KINDS``); a kind a target lacks is absent
    scenario_leaves: dict = {}

    def objective(self, seeds, smooth: bool, scenarios: Optional[dict] = None):
        """J(theta, key) on ``seeds``; ``scenarios`` ({kind: spread}) draws each seed's scenario
        (``with_scenarios``)."""
        raise NotImplementedError

    def log_uniform_around(self, names, keys):
        """Random-search draws: each named paper value times exp(U(-log factor, log factor)), one key each."""
        lf = math.log(self.factor)
        return {k: self.paper[k] * jnp.exp(jax.random.uniform(kk, jnp.shape(self.paper[k]), minval=-lf, maxval=lf))
                for k, kk in zip(names, keys)}

    def grid(self, n):
        """The landscape: ``param`` on a geometric grid within paper value x/÷ factor, the others at the paper's."""
        v = float(self.paper[self.param])
        return [{**self.paper, self.param: jnp.asarray(g)} for g in np.geomspace(v / self.factor, v * self.factor, n)]


class CPXTarget(Target):
    """gamma of CPX on the DIP stabilisation scenario ``jaxdip.scenarios.dip_cpx_ldf`` (its defaults: printed DIP,
    power-series control, encoders, input disturbance) over ``duration``, through ``jaxdip.monte_carlo``."""

    name, param = "cpx", "gamma"

    def __init__(self, cfg: TuneConfig, quanta=None):
        import dataclasses

        from jaxdip.scenarios import dip_cpx_ldf as S

        kw = {} if quanta is None else {"encoder_quanta": tuple(quanta)}
        self.scenario = S.DipCpxLdf(duration=cfg.duration, substeps=cfg.substeps, **kw)
        self.rollouts = {smooth: dataclasses.replace(self.scenario, straight_through=smooth).rollout("cpx")
                         for smooth in (False, True)}
        self.with_gamma = S.with_gamma
        self.paper = {"gamma": jnp.asarray(self.scenario.cpx_gamma)}
        self.spec = {"gamma": Log()}
        self.penalty = cfg.divergence_penalty
        self.deg2 = (180.0 / math.pi) ** 2
        self.lo, self.hi = cfg.search_low, cfg.search_high

    def loss(self, sol):
        """Per seed: time variance of alpha plus that of theta (deg^2), plus the penalty if it diverged."""
        from jaxdip.engine import RESULTS

        var = sol.metrics["x"]["var"]
        return self.deg2 * (var[..., 1] + var[..., 2]) + self.penalty * (sol.result != RESULTS.ok)

    scenario_leaves = {"x0": [lambda r: r.x0.radius], "disturbance": [lambda r: r.loop.actuator.white_std]}

    def objective(self, seeds, smooth: bool, scenarios: Optional[dict] = None):
        from jaxdip.engine import monte_carlo

        seeds = np.asarray(seeds)
        if seeds.size == 0 or np.any(np.diff(seeds) != 1):
            raise ValueError("the cpx target's seeds must be consecutive (monte_carlo's offset .. offset + n - 1)")
        offset, n = int(seeds[0]), int(seeds.size)
        base = self.rollouts[bool(smooth)]

        def per_seed(theta, key):
            r = with_scenarios(self.with_gamma(base, theta["gamma"]), self.scenario_leaves, scenarios)
            return self.loss(monte_carlo(r, key, n, offset=offset, shard=False))

        return Objective(per_seed)

    def sample(self, key):
        return {"gamma": jnp.exp(jax.random.uniform(key, minval=math.log(self.lo), maxval=math.log(self.hi)))}

    def grid(self, n):
        return [{"gamma": jnp.asarray(g)} for g in np.geomspace(self.lo, self.hi, n)]


class RWPTarget(Target):
    """k_p1, k_p2, alpha_p of the HOMD (10) and L0 of the reduced-order bias observer, joint form (24), on the
    reaction-wheel pendulum loop of ``jaxdip.scenarios.rwp`` (Table 2 feedback, sensor bias d = -0.08 rad,
    quantised encoders) from theta0 = 0.1 rad. Loss per seed: int theta^2 dt + wheel_weight * int theta_r'^2 dt
    (+ the divergence penalty)."""

    name, param = "rwp", "L0"
    HOMD = (5.0, 12.0, 0.9)  # Table 2: [k1, k2, alpha] of (10) and (12)
    L0, BIAS, THETA0, OBSERVER_SUBSTEPS = 0.01, -0.08, 0.1, 10

    def __init__(self, cfg: TuneConfig, quantize=None):
        from jaxdip.estimators import bias_observers as bo
        from jaxdip.estimators import homd
        from jaxdip.plants import rwp
        from jaxdip.scenarios import rwp as scenario

        self.dt = rwp.DT
        self.n_steps = int(round(cfg.duration / self.dt))
        hp = homd.homd_params(pend=self.HOMD, wheel=self.HOMD)
        est = bo.JointObserver.of(bo.joint_params(hp, self.L0), self.dt, substeps=self.OBSERVER_SUBSTEPS)
        q = True if quantize is None else bool(quantize)
        kw = dict(steps=self.n_steps, theta0=self.THETA0, dt=self.dt, substeps=cfg.substeps, d=self.BIAS,
                  quantize=q)
        self.rollouts = {smooth: scenario.rollout(est, straight_through=smooth, **kw) for smooth in (False, True)}
        kp1, kp2, ap = self.HOMD
        self.paper = {k: jnp.asarray(v, dtype=jnp.float64)
                      for k, v in (("k_p1", kp1), ("k_p2", kp2), ("alpha_p", ap), ("L0", self.L0))}
        self.spec = {"k_p1": Log(), "k_p2": Log(), "alpha_p": Bounded(0.5, 1.0), "L0": Log()}
        self.penalty, self.w = cfg.divergence_penalty, cfg.wheel_weight
        self.factor = cfg.search_factor

    @staticmethod
    def _where(r):
        e = r.loop.estimator
        return e.homd.pend.k1, e.homd.pend.k2, e.homd.pend.alpha, e.L0

    scenario_leaves = {"x0": [lambda r: r.x0.theta0], "bias": [lambda r: r.loop.sensor.const_bias]}

    def objective(self, seeds, smooth: bool, scenarios: Optional[dict] = None):
        import jaxdip as jd

        seeds = np.asarray(seeds)
        if seeds.size == 0 or np.any(np.diff(seeds) != 1):
            raise ValueError("the rwp target takes consecutive seeds")
        rollout, offset, n = self.rollouts[bool(smooth)], int(seeds[0]), int(seeds.size)

        def per_seed(theta, key):
            r = eqx.tree_at(self._where, rollout, (theta["k_p1"], theta["k_p2"], theta["alpha_p"], theta["L0"]))
            sol = jd.monte_carlo(with_scenarios(r, self.scenario_leaves, scenarios), key, n, offset=offset)
            x2 = sol.metrics["x2"]
            return self.dt * (x2[:, 0] + self.w * x2[:, 3]) + self.penalty * (sol.result != jd.RESULTS.ok)

        return Objective(per_seed)

    def sample(self, key):
        ks = jax.random.split(key, 4)
        out = self.log_uniform_around(("k_p1", "k_p2", "L0"), ks[:3])
        out["alpha_p"] = jax.random.uniform(ks[3], minval=0.5 + 1e-3, maxval=1.0)
        return out



class DMSOTarget(Target):
    """Gamma and K_MSO = diag(k_1..k_4) (both through log) of the DMSO on the noisy TWIP case of
    ``jaxdip.scenarios.twip_dmso`` (Table 8.2 truth, §7.4 sensors with the complementary filter, LQR clipped at
    11.1 V; the values of ``twip-dmso``). Loss per seed = mean over the four states of the RMS estimation error
    over samples 1..T-1 (``twip_dmso.rms_error``; periods after a fall are not counted) + the divergence
    penalty. ``quantum`` overrides the encoder quantum (0: off)."""

    name, param = "dmso", "Gamma"

    def __init__(self, cfg: TuneConfig, quantum=None):
        from jaxdip.scenarios import twip_dmso as S
        from jaxdip.scenarios.twip_initial import thesis_x0

        dt = 0.01
        d = S.design(dt)
        kw = {} if quantum is None else {"encoder_quantum": float(quantum)}
        est = S.estimator("dmso", d)
        self.n_steps = int(round(cfg.duration / dt))
        self.runs = {mode: S.rms_error(S.loop(est, S.sensors(dt, True, encoder_gradient=mode, **kw), d),
                                       thesis_x0(), self.n_steps)
                     for mode in ("exact", "straight_through")}
        self.paper = {"Gamma": jnp.asarray(est.Gamma, dtype=jnp.float64),
                      "K": jnp.asarray(jnp.diag(est.K), dtype=jnp.float64)}
        self.spec = {"Gamma": Log(), "K": Log()}
        self.penalty, self.factor = cfg.divergence_penalty, cfg.search_factor

    def make_run(self, theta, smooth: bool):
        import equinox as eqx

        run = self.runs["straight_through" if smooth else "exact"]
        return eqx.tree_at(lambda r: (r.rollout.loop.estimator.Gamma, r.rollout.loop.estimator.K), run,
                           (theta["Gamma"], jnp.diag(theta["K"])))

    scenario_leaves = {"x0": [lambda run: run.rollout.x0.x0]}

    def objective(self, seeds, smooth: bool, scenarios: Optional[dict] = None):
        import jaxdip as jd
        from jaxdip.scenarios.twip_initial import seed_runs

        runs = seed_runs(np.asarray(seeds))

        def per_seed(theta, key):
            run = with_scenarios(self.make_run(theta, smooth), self.scenario_leaves, scenarios)
            parts = [jd.monte_carlo(run, key, n, offset=off) for off, n in runs]
            return jnp.concatenate([e + self.penalty * d for e, d in parts])

        return Objective(per_seed)

    def sample(self, key):
        return self.log_uniform_around(("Gamma", "K"), jax.random.split(key))


class RPTarget(Target):
    """gamma of the continuous relaxed projection control (2.14) on the printed DIP with a fixed P = P_{V,s}:
    V = v1, the LQR-derived leading Riccati eigenvector (``jaxdip.scenarios.eki_dip.lqr_direction`` with
    eki-dip's LQR weights), s = 1e6 (the README's eki-dip P is given only by its singular values). The eki-dip
    search setup (``jaxdip.scenarios.eki_dip.search_setup``: 1 ms, state noise 5e-5 every period,
    Q = diag(80, 300, 100)) over ``duration`` with t* = duration / 3 (eki-dip: 1 s of 3 s). Loss per seed = log
    of (2.24) with the thesis's failure rule (a state norm above 10 scores log 1000, constant in gamma). Paper
    value gamma = 40 (thesis §3.2.2, the value eki-dip judges with)."""

    name, param = "rp", "gamma"
    # drawn in ``objective`` itself (the trial is a function, not a Module): the setup's x0_std and noise_std
    scenario_leaves = {"x0": [], "disturbance": []}

    def __init__(self, cfg: TuneConfig):
        from jaxdip.control.spd import P_Vs
        from jaxdip.scenarios import eki_dip as S

        self.plant = S.plant()
        A, B = jd.linearize(self.plant)
        self.v1 = S.lqr_direction(A, B)
        self.P = P_Vs(self.v1[:, None], jnp.asarray([1e6]))
        self.scfg = S.search_setup(T=cfg.duration, t_star=cfg.duration / 3.0)
        self.paper = {"gamma": jnp.asarray(S.JUDGE_GAMMA, dtype=jnp.float64)}
        self.spec = {"gamma": Log()}
        self.factor = cfg.search_factor

    def objective(self, seeds, smooth: bool, scenarios: Optional[dict] = None):
        from jaxdip.search.p_search import BasisMember, continuous_performance

        seeds = np.asarray(seeds)
        if seeds.size == 0 or np.any(np.diff(seeds) != 1):
            raise ValueError("the rp target takes consecutive seeds")
        offset, n = int(seeds[0]), int(seeds.size)
        # a one-vector member whose P_{V,s} is self.P (member_P re-derives it from V and log s)
        member = BasisMember(self.v1[None, :], jnp.log(jnp.asarray([1e6])))

        sx = float((scenarios or {}).get("x0", 0.0))
        sd = float((scenarios or {}).get("disturbance", 0.0))

        def per_seed(theta, key):
            base = self.scfg._replace(gamma=theta["gamma"])

            def trial(k):
                cfg = base
                if sx > 0 or sd > 0:  # the held-out scenario: ScenarioDraw's rule on the setup's two stds
                    kx, kd = jax.random.split(jax.random.fold_in(k, SCENARIO_TAG))
                    cfg = base._replace(x0_std=base.x0_std * scenario_factor(kx, sx, jnp.shape(base.x0_std)),
                                        noise_std=base.noise_std * scenario_factor(kd, sd))
                return jnp.log(continuous_performance(self.plant, cfg)(member, k)[0])

            # seed i's key is fold_in(key, i), the driver's convention
            return jd.monte_carlo(trial, key, n, offset=offset, shard=False)

        return Objective(per_seed)

    def sample(self, key):
        return self.log_uniform_around(("gamma",), (key,))


class ExtraTarget(Target):
    """k1 (93), k2 (101) and the learning rates gamma11, gamma12, gamma21, gamma22 (111)-(114) of the TWIP
    extra control (``jaxdip.scenarios.twip_extra``, system ``extra``) on its ``unmodeled`` case (Table 8.2
    truth plus the unmodeled accelerations (185)), all through log. Everything else is the scenario's default
    (the values of ``twip-extra-control``), except the horizon and the RK4 sub-steps.
    Loss per seed = Table 8.3's score sum_k ||x_k - x_d,k|| over ``duration`` + the divergence penalty (a
    diverged seed's state is frozen where it left the bounds, so its score keeps growing with the remaining
    samples and the gradient still sees *when* it fell). Seed i is that study's seed i (network input
    weights V1, V2 and the x0 spread; seed 0 starts at (184)), under the tune experiment's key."""

    name, param = "extra", "k1"
    KEYS = ("k1", "k2", "gamma11", "gamma12", "gamma21", "gamma22")
    SPREAD = 0.1  # twip-extra-control's init_spread

    def __init__(self, cfg: TuneConfig):
        from jaxdip.scenarios import twip_extra as S
        from jaxdip.scenarios.twip_initial import thesis_x0

        self.S = S
        self.dt = 0.01
        self.loop = S.loop("unmodeled", "extra", S.controller(dt=self.dt), dt=self.dt, substeps=cfg.substeps)
        self.n_steps = int(round(cfg.duration / self.dt))
        self.x0 = thesis_x0()
        self.paper = {k: jnp.asarray(getattr(self.loop.controller, k), dtype=jnp.float64) for k in self.KEYS}
        self.spec = {k: Log() for k in self.KEYS}
        self.penalty, self.factor = cfg.divergence_penalty, cfg.search_factor

    def make_loop(self, theta):
        import equinox as eqx

        return eqx.tree_at(lambda lp: tuple(getattr(lp.controller, k) for k in self.KEYS), self.loop,
                           tuple(theta[k] for k in self.KEYS))

    def describe(self):
        # the law's defaults live in the scenario and may change: record the ones this run used
        c = self.loop.controller
        return {"twip_extra_scenario": {"case": "unmodeled", "system": "extra", "dt": self.dt,
                                        "substeps": self.loop.substeps, "init_spread": self.SPREAD,
                                        "x0": np.asarray(self.x0).tolist(), "n_hidden": c.n_hidden,
                                        **{k: np.asarray(getattr(c, k)).tolist()
                                           for k in ("K", "k1", "k2", "b1", "gamma11", "gamma12", "gamma21",
                                                     "gamma22", "sigma11", "sigma12", "sigma21", "sigma22",
                                                     "u_max", "v_scale", "a_virtual", "beta", "tau_d", "ff")}}}

    scenario_leaves = {"x0": [lambda s: s.rollout.x0.x0],
                       "disturbance": [lambda s: s.rollout.loop.plant.g1, lambda s: s.rollout.loop.plant.g2]}

    def objective(self, seeds, smooth: bool, scenarios: Optional[dict] = None):
        import jaxdip as jd
        from jaxdip.scenarios.twip_initial import seed_runs

        seeds = np.asarray(seeds)

        def score_div(theta, key):
            if not scenarios:
                return self.S.scores_at(self.make_loop(theta), self.x0, self.SPREAD, self.n_steps, key, seeds)
            # scores_at's runs with each seed's scenario drawn (seed 0 would start at its drawn x0)
            run = with_scenarios(self.S.scored(self.make_loop(theta), self.x0, self.SPREAD, self.n_steps),
                                 self.scenario_leaves, scenarios)
            parts = [jd.monte_carlo(run, key, n, offset=off, index=True) for off, n in seed_runs(seeds)]
            return jnp.concatenate([p[0] for p in parts]), jnp.concatenate([p[1] for p in parts])

        def per_seed(theta, key):
            s, d = score_div(theta, key)
            return s + self.penalty * d

        return Objective(per_seed, diverged=lambda theta, key: score_div(theta, key)[1])

    def sample(self, key):
        return self.log_uniform_around(self.KEYS, jax.random.split(key, len(self.KEYS)))


def make_target(cfg: TuneConfig, **kw) -> Target:
    return {"cpx": CPXTarget, "rwp": RWPTarget, "dmso": DMSOTarget, "rp": RPTarget,
            "extra": ExtraTarget}[cfg.target](cfg, **kw)


# ---- run ----------------------------------------------------------------------------------------------------


def _scalar(theta):
    return {k: float(v) if np.ndim(v) == 0 else np.asarray(v, dtype=float).tolist() for k, v in theta.items()}


def run(cfg: TuneConfig, ctx: RunContext | None = None, progress: bool = True) -> Outcome:
    import time

    t_all = time.perf_counter()
    tg = make_target(cfg)
    key = jax.random.PRNGKey(cfg.seed)
    tune_seeds = np.arange(cfg.seeds)
    held_seeds = HELDOUT_OFFSET + np.arange(cfg.heldout_seeds)
    J_tune = tg.objective(tune_seeds, smooth=cfg.smoothing == "straight_through")
    J_eval = effort.jit(tg.objective(tune_seeds, smooth=False))  # forward values are the same; no gradient needed
    held_obj = tg.objective(held_seeds, smooth=False, scenarios=cfg.scenario_spreads())
    held = effort.jit(held_obj.per_seed)
    held_div = effort.jit(held_obj.diverged) if held_obj.diverged is not None else None

    res = tune(J_tune, tg.paper, key, steps=cfg.steps, lr=cfg.lr, spec=tg.spec, clip=cfg.clip,
               optimizer=optax.rprop(cfg.lr) if cfg.optimizer == "rprop" else None,
               common_random_numbers=cfg.crn, early_stop_patience=cfg.patience or None,
               checkpoint_path=ctx.checkpoint_path if ctx else None, resume=bool(ctx and ctx.resume),
               fingerprint=ctx.fingerprint if ctx else ckpt.fingerprint(C.to_dict(cfg)), progress=progress, desc=f"tune {cfg.target}",
               mode=cfg.mode)
    sims_grad = res.steps * cfg.seeds
    # random search with the same number of closed-loop simulations, on the same seeds and key
    rs = random_search(lambda th: J_eval(th, key), tg.sample, res.steps, jax.random.fold_in(key, 7),
                       progress=progress, desc=f"random search {cfg.target}")
    best_rs = rs.loss
    hit = np.nonzero(np.minimum.accumulate(res.loss_history) <= best_rs)[0]
    sims_to_rs_best = int((hit[0] + 1) * cfg.seeds) if hit.size else None
    rs_sims_to_best = int((int(np.argmin(rs.losses)) + 1) * cfg.seeds)
    # a forward-mode step carries one tangent per unconstrained coordinate through the same trajectories, so it
    # costs more than one plain evaluation; its measured steady-state price (compilation excluded) converts the
    # gradient's simulation count into evaluation-equivalents, the currency of the random search
    sw, ew = res.step_wall[1:], rs.eval_wall[1:]
    sw, ew = sw[np.isfinite(sw)], ew[np.isfinite(ew)]
    step_cost = float(np.median(sw) / np.median(ew)) if sw.size and ew.size else float("nan")

    t0 = time.perf_counter()
    evals, per_seed = {}, {}
    for name, th in (("paper", tg.paper), ("tuned", res.theta), ("random_search", rs.theta)):
        per_seed[name] = np.asarray(held(th, key))
        evals[name] = stats.mean_ci(per_seed[name])
        if held_div is not None:
            evals[name] += (int(np.sum(held_div(th, key))),)
    diff = stats.mean_ci(per_seed["tuned"] - per_seed["paper"])  # paired: the same held-out seeds' noise
    eval_wall = time.perf_counter() - t0
    land = [float(J_eval(th, key)) for th in tg.grid(cfg.landscape_points)]
    grid = [float(th[tg.param]) for th in tg.grid(cfg.landscape_points)]

    paper_ci, tuned_ci = evals["paper"][1], evals["tuned"][1]
    out = {
        "paper_value": _scalar(tg.paper), "tuned_value": _scalar(res.theta),
        "random_search_value": _scalar(rs.theta),
        "loss_paper": evals["paper"][0], "loss_paper_ci95": paper_ci,
        "loss_tuned": evals["tuned"][0], "loss_tuned_ci95": tuned_ci,
        "loss_random_search": evals["random_search"][0], "loss_random_search_ci95": evals["random_search"][1],
        **({f"heldout_diverged_{n}": evals[n][2] for n in evals} if held_div is not None else {}),
        "heldout_scenario_spreads": {k: v for k, v in cfg.scenario_spreads().items() if k in tg.scenario_leaves},
        "tuned_below_paper_nonoverlapping": bool(tuned_ci[1] < paper_ci[0]),
        "loss_tuned_minus_paper": diff[0], "loss_tuned_minus_paper_ci95": diff[1],
        "simulations_used": sims_grad, "random_search_simulations": int(res.steps * cfg.seeds),
        "tuning_loss_best": res.loss, "random_search_tuning_loss_best": best_rs,
        "gradient_simulations_to_reach_random_search_best": sims_to_rs_best,
        "random_search_simulations_to_its_best": rs_sims_to_best,
        "steps": res.steps, "stopped_early": res.stopped_early,
        "trajectory": {"loss": res.loss_history.tolist(),
                       **{k: np.asarray(v).tolist() for k, v in res.theta_history.items()},
                       "grad_norm": res.grad_norm_history.tolist()},
        "random_search_losses": rs.losses.tolist(),
        "random_search_samples": {k: np.asarray(v).tolist() for k, v in rs.samples.items()},
        "landscape": {tg.param: grid, "loss": land},
    }
    # measured time, and what is derived from it, is not a result: a resumed run must give identical results
    timing = {
        "wall_s": {"tune": res.wall_s, "random_search": rs.wall_s, "heldout_eval": eval_wall,
                   "total": time.perf_counter() - t_all},
        "gradient_step_cost_in_evaluations": step_cost,
        "gradient_evaluation_equivalents_to_reach_random_search_best":
            None if sims_to_rs_best is None else sims_to_rs_best * step_cost,
    }
    if hasattr(tg, "describe"):
        out.update(tg.describe())
    results = {cfg.target: out}
    figures = {"tune_" + cfg.target: figure(cfg, tg, out)}
    return Outcome(results=results, report=report(cfg, out, timing), figures=figures,
                   timing={cfg.target: timing})


def figure(cfg, tg, r):
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
    L = np.asarray(r["trajectory"]["loss"])
    a1.plot(np.arange(1, len(L) + 1) * cfg.seeds, L, "o-", ms=3, label="gradient (Adam), J at each step")
    rsl = np.asarray(r["random_search_losses"])
    a1.plot(np.arange(1, len(rsl) + 1) * cfg.seeds, np.minimum.accumulate(rsl), "s--", ms=3,
            label="random search, best so far")
    a1.set_xlabel("closed-loop simulations (tuning seeds x steps)")
    a1.set_ylabel("J on the tuning seeds")
    a1.set_title(f"{cfg.target}: J against optimiser steps ({cfg.seeds} seeds/step)")
    a1.legend(fontsize=8)
    p = tg.param
    a2.plot(r["landscape"][p], r["landscape"]["loss"], "o-", ms=3, label="J (tuning seeds)")
    a2.axvline(r["paper_value"][p], color="C2", ls=":", label=f"paper {r['paper_value'][p]:.4g}")
    a2.axvline(r["tuned_value"][p], color="C3", ls="--", label=f"tuned {r['tuned_value'][p]:.4g}")
    a2.set_xscale("log")
    if min(r["landscape"]["loss"]) > 0:  # rp's loss is a log already
        a2.set_yscale("log")
    a2.set_xlabel(p)
    a2.set_ylabel("J")
    a2.set_title(f"loss landscape along {p}")
    a2.legend(fontsize=8)
    for a in (a1, a2):
        a.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig


def report(cfg, r, timing) -> str:
    p = list(r["paper_value"])
    num = lambda v: f"{v:.5g}" if np.ndim(v) == 0 else "[" + ", ".join(f"{x:.4g}" for x in v) + "]"
    fmt = lambda d: ", ".join(f"{k} = {num(v)}" for k, v in d.items())
    g = r["gradient_simulations_to_reach_random_search_best"]
    n_tan = sum(int(np.size(v)) for v in r["paper_value"].values())
    lines = [
        f"Target {cfg.target}: tuned {', '.join(p)} on {cfg.seeds} seeds ({cfg.duration} s each, "
        f"{'common random numbers' if cfg.crn else 'resampled keys'}, {'Adam lr' if cfg.optimizer == 'adam' else 'Rprop initial step'} {cfg.lr} on "
        f"log-parameters, clip {cfg.clip}, {cfg.mode}-mode derivatives, quantiser derivative: "
        f"{cfg.smoothing if cfg.target in ('cpx', 'rwp', 'dmso') else 'n/a, no quantiser'}); {r['steps']} steps"
        f"{' (stopped early)' if r['stopped_early'] else ''}. Held-out: {cfg.heldout_seeds} disjoint seeds, "
        + (("each drawing its scenario: " + ", ".join(f"{k} x (1 + U(-{v:g}, {v:g}))"
                                                    for k, v in r["heldout_scenario_spreads"].items() if v > 0)
            + " (the tuning seeds keep the nominal scenario).")
           if any(v > 0 for v in r["heldout_scenario_spreads"].values()) else "in the tuning scenario."),
        "",
        "| | value | held-out loss (95% interval) |",
        "|---|---|---|",
        f"| paper | {fmt(r['paper_value'])} | {fmt_ci(r['loss_paper'], r['loss_paper_ci95'])} |",
        f"| gradient-tuned | {fmt(r['tuned_value'])} | {fmt_ci(r['loss_tuned'], r['loss_tuned_ci95'])} |",
        f"| random search ({r['random_search_simulations']} sims) | {fmt(r['random_search_value'])} | "
        f"{fmt_ci(r['loss_random_search'], r['loss_random_search_ci95'])} |",
        "",
        *([f"Held-out seeds diverged (each counted with the penalty {cfg.divergence_penalty:g}): paper "
           f"{r['heldout_diverged_paper']}, tuned {r['heldout_diverged_tuned']}, random search "
           f"{r['heldout_diverged_random_search']} of {cfg.heldout_seeds}.", ""]
          if "heldout_diverged_paper" in r else []),
        f"Tuned below paper with non-overlapping intervals: {'yes' if r['tuned_below_paper_nonoverlapping'] else 'no'}"
        f"; paired difference tuned - paper on the same held-out seeds: "
        f"{fmt_ci(r['loss_tuned_minus_paper'], r['loss_tuned_minus_paper_ci95'])}."
        f" Best tuning-seed loss: gradient {r['tuning_loss_best']:.5g}, random search "
        f"{r['random_search_tuning_loss_best']:.5g}; the gradient run "
        f"{f'reached the random search best after {g} simulations' if g is not None else 'did not reach the random search best within its budget'}"
        f", the random search found it after "
        f"{r['random_search_simulations_to_its_best']}. A gradient step (one forward-mode pass per seed carrying "
        f"{n_tan} tangent{'s' if n_tan > 1 else ''}) cost "
        f"{timing['gradient_step_cost_in_evaluations']:.3g}x a plain evaluation in wall time (medians, compilation "
        f"excluded), so in evaluation-equivalents the gradient run needed "
        f"{'n/a' if g is None else format(timing['gradient_evaluation_equivalents_to_reach_random_search_best'], '.4g')}"
        f" simulations to reach the random search's best.",
    ]
    return "\n".join(lines)


EXPERIMENT = Experiment(
    id="tune",
    title="Gradient-based tuning of estimator and controller hyperparameters",
    config_cls=TuneConfig,
    run=run,
    quick={"seeds": 4, "heldout_seeds": 16, "duration": 0.5, "steps": 6, "landscape_points": 5},
    source="the documents' hyperparameter values (CPX gamma = 150, paper §5) against gradient tuning",
    quick_effort="fast",  # compiling dominates its quick run (measured)
    resumable=True,
)
