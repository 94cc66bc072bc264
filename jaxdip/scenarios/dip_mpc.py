"""The printed DIP with a motor-voltage limit under constrained linear MPC, LQR with saturation and relaxed
projection control with saturation (an extension beyond the documents: they give no MPC and no voltage limit for
the DIP).

* ``Setup``: the loop's numbers (period, limit, track limit, horizon, weights);
* ``controllers(setup)``: the three controllers, all on the linearisation at upright; LQR is the discrete LQR of
  the same sampled model (so the unconstrained MPC is exactly it), RP is (2.14) with the library's P
  (``jaxdip.control.spd``: the switching surface from the LQR's slow poles), both clipped at the limit;
* ``rollout(setup, controller, x0_scale)``: one Monte Carlo trial from the eki-dip study's random initial states
  (Gaussian, std ``jaxdip.scenarios.eki_dip.X0_STD`` on the positions) scaled by ``x0_scale``, with its metrics;
* ``mpc_cost(setup)``: the tuning objective's per-seed closed-loop cost (quadratic in the states and the input).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.control.feedback import SaturatedFeedback
from jaxdip.control.mpc import LinearMPC
from jaxdip.control.projection import RelaxedProjection
from jaxdip.control.designs import dlqr, lqr
from jaxdip.control.spd import P_v, surface_normal
from jaxdip.engine.driver import Gaussian
from jaxdip.plants import dip
from jaxdip.scenarios.eki_dip import X0_STD
from jaxdip.sim.actuators import Saturation

INF = float("inf")


@dataclass(frozen=True)
class Setup:
    dt: float = 0.01  # control period (s)
    substeps: int = 10  # RK4 steps per period
    duration: float = 5.0
    u_max: float = 6.0  # motor voltage limit (V)
    track: float = 0.4  # |xc| limit (m): counted as a violation for every controller
    track_in_mpc: bool = False  # the track also as the MPC's soft state limit (60 QP rows instead of 20)
    horizon: int = 20
    Q: tuple = (30.0, 350.0, 100.0, 0.0, 0.0, 0.0)
    R: float = 0.1
    slack_weight: float = 1e4
    qp_max_iter: int = 40  # active-set iterations per period (warm-started; QPCode.MAX_ITERATIONS beyond)
    rp_gamma: float = 40.0
    rp_surface_s: float = 1e6
    rp_extra_pole: float = -20.0
    stabilized_tol: float = 0.02
    state_bound: tuple = (1.0, 1.5708, 1.5708, INF, INF, INF)

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.dt))


def mpc(s: Setup, Q=None, R=None) -> LinearMPC:
    """The MPC of ``s`` (weights ``Q`` (6, 6) and ``R`` (1, 1) instead of the setup's if given)."""
    Q = jnp.diag(jnp.asarray(s.Q)) if Q is None else Q
    R = jnp.array([[s.R]]) if R is None else R
    x_lim = np.array([s.track if s.track_in_mpc else INF] + [INF] * 5)
    return LinearMPC.for_plant(dip.DIP(), s.dt, Q, R, s.horizon, u_min=-s.u_max, u_max=s.u_max, x_min=-x_lim,
                               x_max=x_lim, slack_weight=s.slack_weight,
                               max_iter=s.qp_max_iter)


def controllers(s: Setup) -> dict:
    """{"mpc", "lqr_sat", "rp_sat"}: each a (controller, actuator) pair."""
    m = mpc(s)
    K, _, _ = dlqr(m.A, m.B, m.Q, m.R)
    plant = dip.DIP()
    A, B = jd.linearize(plant)
    _, _, E = lqr(A, B, m.Q, m.R)
    E = np.asarray(E)
    c = surface_normal(A, B, np.concatenate([E[np.argsort(-E.real)][:4], [s.rp_extra_pole]]))
    sat = Saturation(jnp.array([-s.u_max]), jnp.array([s.u_max]))
    return {"mpc": (m, jd.Identity()),
            "lqr_sat": (SaturatedFeedback(K, -s.u_max, s.u_max), jd.Identity()),
            "rp_sat": (RelaxedProjection(plant, P_v(c, s.rp_surface_s), s.rp_gamma), sat)}


def _stage(x, u, s: Setup):
    return x @ (jnp.asarray(s.Q) * x) + s.R * u @ u


def rollout(s: Setup, controller, actuator=None, x0_scale: float = 1.0, steps: int | None = None) -> jd.Rollout:
    """A trial: noise-free full-state feedback from x0 ~ N(0, diag(x0_scale X0_STD)^2); metrics as
    ``loop_summary`` reads them, plus the largest |x| (track violations), the quadratic cost over the live
    periods and, for the MPC, its QP's unsolved periods and largest iteration count."""
    loop = jd.Loop(plant=dip.DIP(), sensor=jd.Identity(), estimator=jd.Passthrough(), controller=controller,
                   actuator=jd.Identity() if actuator is None else actuator, dt=s.dt, substeps=s.substeps,
                   state_bound=jnp.asarray(s.state_bound))
    n = s.steps if steps is None else steps
    tail = min(n, int(round(1.0 / s.dt)))
    metrics = {"x": jd.metrics.Moments("x"), "u": jd.metrics.Moments("u_applied"),
               "tail": jd.metrics.Window(jd.metrics.MaxAbs("x"), start=n - tail),
               "max_x": jd.metrics.MaxAbs("x"),
               "cost": jd.metrics.Sum(lambda smp: s.dt * _stage(smp.x, smp.u_applied, s))}
    if isinstance(controller, LinearMPC):  # periods whose QP was not solved (iteration limit), most iterations
        metrics["qp_unsolved"] = jd.metrics.Sum(lambda smp: (smp.aux.controller["status"] != 0).astype(float))
        metrics["qp_iterations"] = jd.metrics.MaxAbs(lambda smp: smp.aux.controller["iterations"].astype(float))
    return jd.Rollout(loop, Gaussian(jnp.zeros(6), x0_scale * jnp.asarray(X0_STD)), n, metrics=metrics)


def tuned_mpc(s: Setup, theta: dict) -> LinearMPC:
    """The MPC with weights theta = {"q": (3,) on xc, alpha, theta; "r": scalar}."""
    Q = jnp.diag(jnp.concatenate([theta["q"], jnp.zeros(3)]))
    return mpc(s, Q, jnp.reshape(theta["r"], (1, 1)))
