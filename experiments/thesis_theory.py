"""thesis-theory: the claims of thesis ch. 1-2 that a computation can check (``jaxdip.theory.proximal_growth``).

* Thm 1.3.2 with the two-measurement functional (1.9): the proximal MHE (1.10) on the Lorenz system with weights
  gamma_k growing as the theorem asks, phi_k(p_k) - min phi_k -> 0 (against constant gamma_k = 1).
* Prop. 1.4.1: the least-squares proximal observer on the DIP's linearisation under LQR, ||p_k - (x_k + zeta_k)||
  -> 0 under the same growth (against constant gamma = 150).
* Prop. 2.4.2: the continuous relaxed projection control (2.14) on the DIP's linearisation with P the LQR Riccati
  solution stays exponentially stable for gamma(t) > zeta (random switching gamma(t)).

A supporting run of the fidelity readings (docs/fidelity/dip.md): not part of a plain ``jaxdip reproduce``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxdip import config as C
from jaxdip.runner.experiment import Experiment, Outcome, RunContext
from jaxdip.runner.weights import weight_matrix


@dataclass
class ThesisTheoryConfig:
    seed: int = C.field(0, C.nonneg, doc="PRNG key of the Lorenz trials (the DIP trials use seed + 1)")
    trials: int = C.field(32, C.positive, doc="trials of Thm 1.3.2 (Lorenz) and of Prop. 1.4.1 (DIP) each")
    lorenz_steps: int = C.field(300, C.positive, doc="Thm 1.3.2: steps of each Lorenz trial (h = 0.01)")
    dip_steps: int = C.field(400, C.positive, doc="Prop. 1.4.1: steps of each DIP trial (1 ms)")
    rp_trials: int = C.field(50, C.positive, doc="Prop. 2.4.2: random gamma(t) trajectories of 5 s")
    Q: list[float] = C.field([30.0, 350.0, 100.0, 1.0, 1.0, 1.0], C.finite, C.length(6),
                             doc="LQR state weight (diagonal) of the DIP loop and of P in Prop. 2.4.2")
    R: float = C.field(0.1, C.positive_finite, doc="LQR input weight")
    tolerance: float = C.field(1e-8, C.positive_finite, doc="a gap or error below this counts as reaching 0")

    @property
    def seeds(self) -> int:  # the header's and metrics.json's seed count
        return self.trials

    def validate(self):
        weight_matrix("Q", self.Q, 6)
        if self.lorenz_steps < 4 or self.dip_steps < 4:
            raise C.ConfigError("lorenz_steps" if self.lorenz_steps < 4 else "dip_steps",
                                "must be at least 4 (the tail is the last quarter of the steps)")


def compute(cfg: ThesisTheoryConfig) -> dict:
    import jax
    import jax.numpy as jnp

    import jaxdip as jd
    from jaxdip.plants import dip
    from jaxdip.scenarios import dip_cpx_ldf as S
    from jaxdip.theory import proximal_growth as pg

    nl = pg.nonlinear_two_measurement(jax.random.PRNGKey(cfg.seed), trials=cfg.trials, steps=cfg.lorenz_steps)
    model, Cm = S.DipCpxLdf().model()
    A, B = jd.linearize(dip.DIP())
    K, Sric, _ = jd.control.lqr(A, B, jnp.diag(jnp.asarray(cfg.Q)), cfg.R)
    Phi_cl = np.asarray(model.Phi) - np.asarray(model.W) @ np.asarray(K)
    li = pg.linear_least_squares(jax.random.PRNGKey(cfg.seed + 1), Phi_cl, np.asarray(Cm), trials=cfg.trials,
                                 steps=cfg.dip_steps)
    rp = pg.relaxed_projection_growth(np.asarray(A), np.asarray(B), np.asarray(Sric), trials=cfg.rp_trials)
    tol = cfg.tolerance

    def mx(a):
        return float(np.max(a))

    def md(a):
        return float(np.median(a))

    return {
        "thm_1_3_2": {
            "trials": len(nl.growth), "steps": cfg.lorenz_steps, "growth_median": md(nl.growth),
            "tail_gap_growing_max": mx(nl.tail_gap_growing), "tail_gap_constant_max": mx(nl.tail_gap_constant),
            "err_growing_max": mx(nl.err_growing), "err_constant_median": md(nl.err_constant),
            "truth_err_growing_median": md(nl.truth_err_growing),
            "truth_err_constant_median": md(nl.truth_err_constant),
            "holds": bool(np.all(nl.tail_gap_growing < tol))},
        "prop_1_4_1": {
            "trials": len(li.growth), "steps": cfg.dip_steps, "growth_median": md(li.growth),
            "err_growing_max": mx(li.err_growing), "err_constant_median": md(li.err_constant),
            "truth_err_growing_median": md(li.truth_err_growing),
            "truth_err_constant_median": md(li.truth_err_constant),
            "holds": bool(np.all(li.err_growing < tol))},
        "prop_2_4_2": {
            "trials": len(rp.worst_ratio), "zeta": float(rp.zeta), "alpha": float(rp.alpha),
            "rate_max": mx(rp.rates), "constant_weights": len(rp.rates), "worst_ratio_max": mx(rp.worst_ratio),
            "final_ratio_max": mx(rp.final_ratio),
            "holds": bool(np.all(rp.rates <= -rp.alpha + 1e-12) and np.all(rp.worst_ratio <= 1 + 1e-9))},
    }


def report(cfg: ThesisTheoryConfig, r: dict) -> str:
    nl, li, rp = r["thm_1_3_2"], r["prop_1_4_1"], r["prop_2_4_2"]

    def yn(b):
        return "yes" if b else "no"

    q = ", ".join(f"{v:g}" for v in cfg.Q)
    return "\n".join([
        "| claim | set-up | ours | holds |",
        "|---|---|---|---|",
        f"| Thm 1.3.2 with the two-measurement functional (1.9) | Lorenz, RK4 map h = 0.01, y = (yL, zL), "
        f"{nl['trials']} trials of {nl['steps']} steps; gamma_k = gamma_0 rho^k with rho the largest ratio the "
        f"theorem asks for along the trial (median {nl['growth_median']:.3g}) | phi_k(p_k) - min phi_k over the "
        f"last quarter: max {nl['tail_gap_growing_max']:.2g} (growing) vs {nl['tail_gap_constant_max']:.2g} "
        f"(gamma_k = 1); error to the truth (median) {nl['truth_err_growing_median']:.3g} vs "
        f"{nl['truth_err_constant_median']:.3g} | {yn(nl['holds'])} |",
        f"| Prop. 1.4.1 | the DIP's linearisation under LQR (Q = diag({q}), R = {cfg.R:g}, ZOH 1 ms), outputs xc, "
        f"alpha, theta, {li['trials']} trials of {li['steps']} steps, growth median {li['growth_median']:.3g} | "
        f"||p_k - (x_k + zeta_k)|| at the end: max {li['err_growing_max']:.2g} (growing) vs median "
        f"{li['err_constant_median']:.3g} (gamma = 150) | {yn(li['holds'])} |",
        f"| Prop. 2.4.2 | the DIP's linearisation, P = the LQR Riccati solution; zeta = {rp['zeta']:.4g}, alpha = "
        f"{rp['alpha']:.3g} at 1.01 zeta; {rp['trials']} trajectories of 5 s with random gamma(t) > zeta | decay "
        f"rate at {rp['constant_weights']} constant weights: max {rp['rate_max']:.3g} (must be <= -alpha); max "
        f"||x(t)||_P e^(alpha t) / ||x_0||_P {rp['worst_ratio_max']:.4g} (must be <= 1); ||x(5)||_P / ||x_0||_P "
        f"max {rp['final_ratio_max']:.3g} | {yn(rp['holds'])} |",
        "",
        f"A gap or error counts as 0 below {cfg.tolerance:g}.",
    ])


def run(cfg: ThesisTheoryConfig, ctx: RunContext | None = None) -> Outcome:
    r = compute(cfg)
    return Outcome(results=r, report=report(cfg, r))


EXPERIMENT = Experiment(
    per_seed=False,  # no Outcome.per_seed yet (docs/data.md)
    id="thesis-theory",
    title="thesis ch. 1-2: Thm 1.3.2 with (1.9), Prop. 1.4.1, Prop. 2.4.2 by computation (fidelity readings)",
    config_cls=ThesisTheoryConfig,
    run=run,
    quick={"trials": 8, "lorenz_steps": 100, "dip_steps": 100, "rp_trials": 10},
    source="thesis Theorem 1.3.2 with (1.9), Proposition 1.4.1, Proposition 2.4.2",
    reproduce=False,
)
