"""eki-dip: ensemble Kalman synthesis of a relaxed projection control for the DIP (thesis §3.2.1), and a
gradient search of the same P parameterisation beside it.

Search (Procedure 1, continuous form): members are two free basis vectors V (rows) and log singular values;
P = P_{V,s} (2.20); the relaxed projection control (2.14) with gamma = 10 is updated every 1 ms on the printed
DIP; the state is perturbed by Gaussian noise every 1 ms; performance (2.24) with Q = diag(80, 300, 100) on
the positions between t* and T; a state norm above 10 ends a simulation with performance 1000. Initial
ensemble as the thesis describes: v1 the leading eigenvector of the LQR Riccati solution, perturbed; v2 small
random perturbations of a vector in v1^perp intersected with B^perp; s around [1e6, 1e5].

The thesis writes the state noise as N(0, 5e-5) and the objectives' parameters are not printed; we read 5e-5
as the standard deviation (see the config). Two choices of ours, both measured on this model: the ensemble works
on log(2.24) (the performance spans orders of magnitude between members, and on the raw scale the linear
update over-steps into the unstable set within ~20 iterations), with yhat = log(3.4e-4) and R = 1 on that scale;
and the initial s_2 is 1e4 rather than the thesis's 1e5, which leaves only ~5% of the initial members
stabilising on the printed model.

The found P (ensemble mean, re-orthonormalised) is judged by Monte Carlo: relaxed projection with gamma = 40
from ``seeds`` random near-upright states for ``judge_duration`` s; stabilised = not diverged and the angles
within ``stabilized_tol`` over the last second.

Gradient search: the same (V, log s) from the same starting point, optimised with Adam (clipped) on the mean
of log(2.24) over ``grad_x0`` training initial states (the same ones every step by default), through the
differentiable closed loop; the best iterate on that loss is kept. Both are
compared by their final performance on common evaluation states and by the number of closed-loop simulations
they used (a gradient step counts its forward simulations; its backward pass costs about as much again).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.resources import Load, steps_of
from jaxdip import checkpoint
from jaxdip import config as C
from jaxdip.runner.experiment import Experiment, Outcome, RunContext
from jaxdip.runner.per_seed import prefixed
from jaxdip.runner.summaries import loop_per_seed, loop_summary
from jaxdip.plants import dip
from jaxdip.progress import Progress
from jaxdip.scenarios import eki_dip as S
from jaxdip.search import EKI, SearchStopped, data_misfit, run_eki
from jaxdip.search.failures import STATUS_NAMES
from jaxdip.search.eki import align_signs
from jaxdip.search.p_search import (
    BasisMember, continuous_performance, member_blocks, member_P, performances, project_member,
)
from jaxdip.tune import tune
from experiments import _eki_dip_variants as variants
from experiments._eki_dip_report import figure, report


@dataclass
class EkiDipConfig:
    seeds: int = C.field(1000, C.positive, doc="random near-upright states judging the found P")
    seed: int = C.field(0, C.nonneg, doc="base PRNG key")
    ensemble: int = C.field(80, C.positive, doc="ensemble size J")
    iterations: int = C.field(1000, C.positive, doc="maximum search iterations")
    chunk: int = C.field(10, C.positive, doc="iterations between progress updates, stop checks and checkpoints")
    stop_below: float = C.field(-6.0, C.finite,
                                doc="stop once the ensemble-mean (log) performance, averaged over the last chunk, "
                                    "is below this")
    early_stop: bool = C.field(True, doc="use stop_below")
    dt: float = C.field(0.001, C.positive_finite, doc="control period and noise interval (s)")
    T: float = C.field(3.0, C.positive_finite, doc="simulated time per evaluation (s)")
    t_star: float = C.field(1.0, C.nonneg_finite, doc="start of the (2.24) window (s)")
    substeps: int = C.field(1, C.positive,
                            doc="RK4 sub-steps per period in the search (1: (2.24) within 9e-10 relative of RK4 x 20)")
    gamma: float = C.field(10.0, C.positive_finite, doc="RP weight during the search")
    Q: list[float] = C.field([80.0, 300.0, 100.0, 0.0, 0.0, 0.0], C.nonneg_finite, C.length(6),
                             doc="(2.24) weight on [xc, alpha, theta, velocities]")
    noise_std: float = C.field(5e-5, C.nonneg_finite, doc="std of the state noise added every period")
    x0_std: list[float] = C.field([0.01, 0.01, 0.01, 0.0, 0.0, 0.0], C.nonneg_finite, C.length(6),
                                  doc="std of the random initial state of an evaluation")
    n_x0: int = C.field(1, C.positive, doc="initial states per evaluation (thesis: 1)")
    log_performance: bool = C.field(True, doc="search on log(2.24) (then y_target and R are on the log scale); "
                                              "(2.24) spans orders of magnitude and the EKI's linear update needs "
                                              "the log to make steady progress")
    failure: str = C.field("penalty", C.one_of("penalty", "resample", "ignore"),
                           doc="failed members: the thesis's penalty (on the log scale a bounded cliff the update "
                               "steers away from), redrawn from the successful ones (loses that information), or "
                               "left out of the update and in place")
    min_success: int = C.field(20, C.positive, doc="resample/ignore: fewer successes skip the iteration (ten "
                                                   "skipped in a row stop the search with an error)")
    variant: str = C.field("eki", C.one_of("eki", "uki"),
                           doc="ensemble Kalman variant: perturbed-observation EKI (thesis) or unscented UKI "
                               "(2p + 1 sigma points instead of the ensemble; failure must be penalty)")
    schedule: str = C.field("fixed", C.one_of("fixed", "adaptive"),
                            doc="step: the thesis's fixed dt = 1, or the data-misfit controller (the search also "
                                "stops at algorithmic time 1)")
    adaptive_end: float = C.field(1.0, C.positive_finite,
                                  doc="algorithmic time at which the adaptive schedule stops (Iglesias & Yang: 1, "
                                      "prior to posterior; larger values keep minimising)")
    y_target: float = C.field(-8.0, C.finite, doc="performance objective yhat (log scale: 3.4e-4)")
    R: float = C.field(1.0, C.positive_finite, doc="variance of the objective's perturbation")
    sigma_w: float = C.field(1e-4, C.nonneg_finite, doc="std of the members' random perturbation")
    init_v_std: float = C.field(0.002, C.nonneg_finite, doc="std of the perturbation of the LQR-derived v1")
    init_v2_std: float = C.field(0.02, C.nonneg_finite, doc="std of the perturbation of v2")
    init_s: list[float] = C.field([1e6, 1e4], C.positive_finite, C.length(2),
                                  doc="initial singular values (thesis: [1e6, 1e5], which leaves ~5% of the "
                                      "initial members stabilising on the printed model; 1e4 leaves ~70%)")
    init_log_s_std: float = C.field(0.1, C.nonneg_finite, doc="std of the initial log singular values")
    lqr_Q: list[float] = C.field([30.0, 350.0, 100.0, 0.0, 0.0, 0.0], C.nonneg_finite, C.length(6),
                                 doc="LQR whose Riccati solution seeds v1")
    lqr_R: float = C.field(0.1, C.positive_finite, doc="that LQR's R")
    judge_gamma: float = C.field(40.0, C.positive_finite, doc="RP weight when judging the found P")
    judge_duration: float = C.field(5.0, C.positive_finite, doc="judging simulations (s)")
    judge_radius: float = C.field(0.03, C.nonneg_finite, doc="judging initial states uniform in this ball")
    stabilized_tol: float = C.field(0.02, C.positive_finite, doc="max |alpha|, |theta| over the last second")
    grad_steps: int = C.field(200, C.nonneg, doc="Adam steps of the gradient search (0 skips it)")
    grad_lr: float = C.field(1e-4, C.positive_finite, doc="Adam learning rate (the stable set is narrow: v1 entries move by ~1e-3)")
    grad_x0: int = C.field(8, C.positive, doc="initial states per gradient step")
    grad_clip: float = C.field(1.0, C.positive_finite, doc="gradient clipping (global norm)")
    grad_common_states: bool = C.field(True, doc="the same training states at every step (else fresh ones)")
    eval_states: int = C.field(64, C.positive, doc="common initial states scoring both searches")
    x0_draw: str = C.field("shared", C.one_of("shared", "per_member"),
                           doc="initial state (and noise) of an iteration: one shared by the ensemble, or drawn per "
                               "member as Procedure 1's steps 1-2 say")
    search_precision: str = C.field("float64", C.one_of("float64", "float32"),
                                    doc="the search's forward model (its closed loops) in float64 or float32 "
                                        "(about half the search's CPU time; not shown safe, so not the default); "
                                        "the ensemble update, the evaluation states, the gradient search and the "
                                        "judge stay float64")
    variants_table: bool = C.field(True, doc="also run the variant table's readings (the fixed step, the adaptive "
                                             "step ending at 1 and at 20, UKI with the fixed step) with this "
                                             "config, each judged like the main search, which is not repeated")
    free_vectors: int = C.field(2, C.one_of(1, 2),
                                doc="free basis vectors: 2 (V and s searched) or 1 (the thesis's first search: v1 "
                                    "alone, its singular value fixed at init_s[0])")

    def loads(self) -> list[Load]:
        n = steps_of(self.T, self.dt)
        return [Load("the ensemble search", ("ensemble", "n_x0", "T"), self.ensemble * self.n_x0, n),
                Load("the gradient search", ("grad_x0", "T"), self.grad_x0 if self.grad_steps else 0, n,
                     saved=60 * n),
                Load("the judging Monte Carlo", ("seeds", "judge_duration"), self.seeds,
                     steps_of(self.judge_duration, self.dt))]

    def validate(self):
        if self.t_star >= self.T:
            raise C.ConfigError("t_star", f"must be below T = {self.T}")
        if self.variant == "uki" and self.failure != "penalty":
            raise C.ConfigError("failure", "variant 'uki' moves a Gaussian, not an ensemble: failure must be "
                                           f"'penalty', got {self.failure!r}")


def projection(cfg):
    """Procedure 1 step 8 (re-orthonormalise), and with one free vector the singular value held at init_s[0]."""
    if cfg.free_vectors == 2:
        return project_member
    log_s1 = float(np.log(cfg.init_s[0]))

    def project(m: BasisMember) -> BasisMember:
        m = project_member(m)
        return BasisMember(m.V, jnp.full_like(m.log_s, log_s1))

    return project


def _search_cfg(cfg):
    return S.search_setup(dt=cfg.dt, T=cfg.T, t_star=cfg.t_star, gamma=cfg.gamma, Q=cfg.Q, noise_std=cfg.noise_std,
                          x0_std=cfg.x0_std, substeps=cfg.substeps)


def initial_ensemble(cfg, A, B, key):
    """Thesis §3.2.1: v1 from the LQR Riccati solution, v2 in v1^perp ∩ B^perp, s near [1e6, 1e5]."""
    v1 = S.lqr_direction(A, B, cfg.lqr_Q, cfg.lqr_R)
    # orthonormal basis of the complement of span{v1, B}: the last 4 left singular vectors of [v1, B]
    Uc = jnp.linalg.svd(jnp.stack([v1, B[:, 0]], axis=1), full_matrices=True)[0][:, 2:]
    k1, k2, k3, k4 = jax.random.split(key, 4)
    J = cfg.ensemble
    v2_dir = Uc @ jax.random.normal(k1, (Uc.shape[1],))
    v2_dir = v2_dir / jnp.linalg.norm(v2_dir)
    V1 = v1 + cfg.init_v_std * jax.random.normal(k2, (J, 6))
    V2 = v2_dir + cfg.init_v2_std * jax.random.normal(k3, (J, 6))
    log_s = jnp.log(jnp.asarray(cfg.init_s)) + cfg.init_log_s_std * jax.random.normal(k4, (J, 2))
    members = BasisMember(jnp.stack([V1, V2], axis=1)[:, : cfg.free_vectors], log_s[:, : cfg.free_vectors])
    return jax.vmap(projection(cfg))(members), v1


def judge(cfg, member, key_seed, name: str = "judge", path: str = "judge"):
    """Monte Carlo of RP with the found P: stabilised fraction over ``seeds`` near-upright states; the summary and
    its per-seed arrays (variables ``<name>.*``, summarised under ``results[path]``)."""
    rollout = S.judge_rollout(member_P(member), gamma=cfg.judge_gamma, dt=cfg.dt, duration=cfg.judge_duration,
                              radius=cfg.judge_radius, noise_std=cfg.noise_std)
    sol = jd.monte_carlo(rollout, jax.random.PRNGKey(key_seed), cfg.seeds, progress=True, desc="eki-dip judge")
    data = loop_per_seed(sol, dip.STATE_NAMES, (1, 2), cfg.stabilized_tol, dt=cfg.dt, state_units=dip.STATE_UNITS,
                         input_units="V")
    r = loop_summary(sol, dip.STATE_NAMES, (1, 2), cfg.stabilized_tol, dt=cfg.dt, bound=S.STATE_BOUND, per_seed=data)
    return r, prefixed(data, name, path, seeds_key=f"PRNGKey({key_seed})")


class GradientLoss(NamedTuple):
    """The gradient search's loss: the mean of log (2.24) (no penalty: the integral up to a failure) over
    ``n`` initial states split from the key, at the re-orthonormalised member."""

    plant: object
    scfg: object
    n: int

    def __call__(self, m, key):
        ys = performances(self.plant, self.scfg, project_member(m), key, self.n, penalize=False)
        return jnp.mean(jnp.log(ys + 1e-12))


def build(cfg: EkiDipConfig, base):
    """The search: the plant, the evaluation setup, the EKI process and its initial state, and the LQR's v1."""
    plant = S.plant()
    A, B = jd.linearize(plant)
    scfg = _search_cfg(cfg)
    members0, v1_lqr = initial_ensemble(cfg, A, B, jax.random.fold_in(base, 1))
    # with one key per iteration for the whole ensemble the noise is drawn once, ahead of the loop (fast);
    # with a key per member it is drawn in the loop, batched
    G32 = continuous_performance(plant, scfg._replace(precision=cfg.search_precision), n_x0=cfg.n_x0,
                                 noise_ahead=cfg.x0_draw == "shared")

    def G0(m, k):  # the closed loops in search_precision, the performance back in float64 for the update
        return G32(m, k).astype(jnp.float64)

    G = (lambda m, k: jnp.log(G0(m, k))) if cfg.log_performance else G0
    eki = EKI(G=G, template=jax.tree_util.tree_map(lambda a: a[0], members0), y_target=jnp.array([cfg.y_target]),
              R=jnp.array([[cfg.R]]), sigma_w=cfg.sigma_w, project=projection(cfg), failure=cfg.failure,
              min_success=cfg.min_success, penalty=float(np.log(scfg.penalty)) if cfg.log_performance else scfg.penalty,
              align=lambda V: align_signs(V, member_blocks(cfg.free_vectors, 6)),
              member_keys=cfg.x0_draw == "per_member", variant=cfg.variant,
              schedule=data_misfit(cfg.adaptive_end) if cfg.schedule == "adaptive" else None)
    return plant, scfg, eki, eki.init(members0, jax.random.fold_in(base, 2)), members0, v1_lqr


def ensemble_search(cfg: EkiDipConfig, eki, state, ctx: RunContext | None, desc: str = "eki-dip search"):
    """run_eki to ``cfg.iterations`` (or the early stop), checkpointed after every chunk to
    ``ctx.checkpoint_path`` and continued from it with ``ctx.resume``. Returns (state, history, wall time)."""
    fp = ctx.fingerprint if ctx is not None else checkpoint.fingerprint(C.to_dict(cfg))
    hist_prev = np.zeros((0, 1))
    wall_before = 0.0
    if ctx is not None and ctx.resume:  # run_experiment has checked that the checkpoint is there
        # the history's length is the iterations done so far: a leading 0 accepts any
        (state, hist_prev), meta = checkpoint.load(ctx.checkpoint_path, (state, jnp.zeros((0, 1))), fp)
        hist_prev = np.asarray(hist_prev)[: int(state.iteration)]
        wall_before = meta.get("wall_s", 0.0)
    t0 = time.perf_counter()
    bar = Progress(cfg.iterations, desc=desc)
    bar.update(int(state.iteration))

    def save(st, h):
        if ctx is not None:
            full = np.concatenate([hist_prev, h]) if len(hist_prev) else h
            checkpoint.save(ctx.checkpoint_path, (st, jnp.asarray(full)), fp,
                            wall_s=wall_before + time.perf_counter() - t0)

    # one random initial state per iteration makes single values noisy: judge the last chunk's average
    stop = (lambda h: float(h[-cfg.chunk:, 0].mean()) < cfg.stop_below) if cfg.early_stop else None
    state, hist_new = run_eki(eki, state, cfg.iterations, chunk=cfg.chunk, progress=bar, checkpoint=save,
                              stop=stop)
    bar.close()
    history = np.concatenate([hist_prev, hist_new]) if len(hist_prev) else hist_new
    return state, history, wall_before + time.perf_counter() - t0


def gradient_search(cfg: EkiDipConfig, plant, scfg, start, key):
    """Adam (clipped) on the mean log (2.24) over ``grad_x0`` training states through ``jaxdip.tune``, the
    basis re-orthonormalised after every step, the best iterate kept.

    Common random numbers: the same training states every step make the loss a deterministic function of P,
    so Adam follows its gradient rather than the noise between initial states; a step can land on a
    trajectory that fails, whose NaN derivatives count as 0."""
    return tune(GradientLoss(plant, scfg, cfg.grad_x0), start, key, steps=cfg.grad_steps, lr=cfg.grad_lr,
                clip=cfg.grad_clip, common_random_numbers=cfg.grad_common_states, mode="reverse",
                project=projection(cfg), zero_nonfinite_grads=True, desc="eki-dip gradient search")


def run(cfg: EkiDipConfig, ctx: RunContext | None = None) -> Outcome:
    base = jax.random.PRNGKey(cfg.seed)
    plant, scfg, eki, state, members0, v1_lqr = build(cfg, base)
    cpu0 = time.process_time()  # every thread of the process: a figure less sensitive than wall time to load
    state, history, eki_wall = ensemble_search(cfg, eki, state, ctx)
    eki_cpu = time.process_time() - cpu0  # of this session (a resumed run: since the resume)
    found = eki.mean(state)
    iters = int(state.iteration)

    def eval_perf(m):  # (2.24) on common evaluation states
        y = np.asarray(performances(plant, scfg, m, jax.random.fold_in(base, 3), cfg.eval_states))
        return {"mean": float(y.mean()), "median": float(np.median(y)), "failed": int((y >= scfg.penalty).sum())}

    start_mean = projection(cfg)(jax.tree_util.tree_map(lambda a: a.mean(0), members0))
    perf_start = eval_perf(start_mean)
    perf_eki = eval_perf(found)

    grad = {}
    if cfg.grad_steps > 0:
        tg = time.perf_counter()
        res = gradient_search(cfg, plant, scfg, start_mean, jax.random.fold_in(base, 4))
        m = res.theta
        grad = {"P_basis": np.asarray(m.V).tolist(), "P_singular_values": np.exp(np.asarray(m.log_s)).tolist(),
                "steps": cfg.grad_steps, "simulations": cfg.grad_steps * cfg.grad_x0,
                "performance": eval_perf(m), "loss_history": [float(x) for x in res.loss_history]}
        grad_wall = time.perf_counter() - tg
        grad["judge"], grad_data = judge(cfg, m, cfg.seed + 7, "gradient_judge", "gradient.judge")
        grad["stabilized_fraction"] = grad["judge"]["stabilized_fraction"]

    judged, data = judge(cfg, found, cfg.seed + 7)
    timing = {"search_wall_s": eki_wall, "search_cpu_s": eki_cpu, **({"gradient_search_wall_s": grad_wall} if grad else {})}
    table = {}
    if cfg.variants_table:
        main = variants.row(iters, int(state.members.shape[0]), cfg.n_x0, "ok", judged, perf_eki)
        table["variants"], timing["variants_wall_s"] = variants.compare(
            cfg, main, eki_wall, lambda key, c: reading_search(c, base, eval_perf, key))
    if grad:
        data.update(grad_data)
    results = {
        "P_basis": np.asarray(found.V).tolist(),
        "P_singular_values": np.exp(np.asarray(found.log_s)).tolist(),
        "v1_lqr": np.asarray(v1_lqr).tolist(),
        "iterations": iters,
        "simulations": iters * int(state.members.shape[0]) * cfg.n_x0,  # members, or UKI's sigma points
        "stabilized_fraction": judged["stabilized_fraction"],
        "stabilized_fraction_ci95": judged["stabilized_fraction_ci95"],
        "judge": judged,
        "performance_start": perf_start,
        "performance": perf_eki,
        "history_mean_performance": history[:, 0].tolist(),
        "gradient": grad,
        **table,
    }
    return Outcome(results, report(cfg, results, timing), {"search_history": figure(cfg, history, grad)},
                   timing=timing, per_seed=data)


def reading_search(cfg: EkiDipConfig, base, evaluate, key: str) -> tuple[dict, float]:
    """A row of the variant table: the search of this reading (from the main search's initial ensemble), its
    wall time, and unless it stopped or ended non-finite, its judge and (2.24) on the evaluation states."""
    _, _, eki, state, _, _ = build(cfg, base)
    points = int(state.members.shape[0])
    t0 = time.perf_counter()
    try:
        state, _, wall = ensemble_search(cfg, eki, state, None, desc=f"eki-dip {key.replace('_', ' ')}")
        status = "ok"
    except SearchStopped as e:  # a diverging reading is a row that says so
        state, wall, status = e.state, time.perf_counter() - t0, STATUS_NAMES[e.status]
    iters = int(state.iteration)
    found = eki.mean(state)
    if status == "ok" and not np.all(np.isfinite(np.asarray(member_P(found)))):
        status = "P_not_finite"  # e.g. UKI's singular values overflowing once every sigma point fails
    if status != "ok":
        return variants.row(iters, points, cfg.n_x0, status), wall
    return variants.row(iters, points, cfg.n_x0, status, judge(cfg, found, cfg.seed + 7)[0], evaluate(found)), wall


EXPERIMENT = Experiment(
    id="eki-dip", title="ensemble Kalman synthesis of relaxed projection control for the DIP", config_cls=EkiDipConfig,
    run=run, quick={"seeds": 32, "ensemble": 8, "iterations": 4, "chunk": 2, "T": 1.0, "t_star": 0.5,
                    "grad_steps": 3, "grad_x0": 2, "eval_states": 8, "judge_duration": 2.0},
    source="thesis §3.2.1, Procedure 1, (2.20), (2.24)",
    resumable=True,
    quick_cost_s=25, full_cost_s=254)
