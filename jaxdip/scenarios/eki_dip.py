"""The printed DIP under relaxed projection control with P = P_{V,s} (thesis §3.2.1): the setup of the
ensemble Kalman search (``eki-dip``) and of the ``rp`` tuning target.

* ``lqr_direction``: v1, the leading eigenvector of the Riccati solution of an LQR on the linearisation at
  upright (sign: along B), the thesis's starting direction for the basis of P;
* ``search_setup``: one evaluation of (2.24): (2.14) with weight ``gamma`` updated every ``dt``, Gaussian state
  noise every period, Q on the positions between t* and T, a state norm above 10 ends it with performance 1000
  (the defaults are eki-dip's);
* ``judge_rollout``: a Monte Carlo trial of (2.14) with a given P from near-upright states, with the metrics
  of ``jaxdip.runner.summaries.loop_summary``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

import jaxdip as jd
from jaxdip.control import lqr
from jaxdip.control.projection import RelaxedProjection
from jaxdip.plants import dip
from jaxdip.search.p_search import ContinuousSearch

INF = float("inf")
LQR_Q = (30.0, 350.0, 100.0, 0.0, 0.0, 0.0)  # Table 3.1's weights
LQR_R = 0.1
SEARCH_Q = (80.0, 300.0, 100.0, 0.0, 0.0, 0.0)  # (2.24) weight on [xc, alpha, theta, velocities]
NOISE_STD = 5e-5  # the thesis's N(0, 5e-5), read as a standard deviation
X0_STD = (0.01, 0.01, 0.01, 0.0, 0.0, 0.0)
STATE_BOUND = (1.0, 1.5708, 1.5708, INF, INF, INF)
JUDGE_GAMMA = 40.0  # the weight of (2.14) the thesis runs the found P with (§3.2.2)


def plant() -> dip.DIP:
    return dip.DIP(variant="printed")


def lqr_direction(A, B, lqr_Q=LQR_Q, lqr_R: float = LQR_R) -> jax.Array:
    """v1: the leading eigenvector of the LQR's Riccati solution, signed to point along B."""
    _, S, _ = lqr(A, B, jnp.diag(jnp.asarray(lqr_Q)), lqr_R)
    w, U = jnp.linalg.eigh(S)
    return U[:, -1] * jnp.sign(U[:, -1] @ B[:, 0])


def search_setup(*, dt: float = 0.001, T: float = 3.0, t_star: float = 1.0, gamma: float = 10.0, Q=SEARCH_Q,
                 noise_std: float = NOISE_STD, x0_std=X0_STD, substeps: int = 2) -> ContinuousSearch:
    return ContinuousSearch(dt=dt, n_steps=int(round(T / dt)), t_star_steps=int(round(t_star / dt)), gamma=gamma,
                            Qpos=jnp.diag(jnp.asarray(Q)), noise_std=noise_std, x0_std=jnp.asarray(x0_std),
                            substeps=substeps)


def judge_rollout(P, *, gamma: float = JUDGE_GAMMA, dt: float = 0.001, duration: float = 5.0, radius: float = 0.03,
                  noise_std: float = NOISE_STD, substeps: int = 10, state_bound=STATE_BOUND) -> jd.Rollout:
    """(2.14) with P and ``gamma`` on the printed DIP, every state measured exactly, state noise every period,
    initial states uniform in a ball of ``radius`` around upright; metrics: state and input moments and the
    largest |x| over the last second."""
    p = plant()
    n = int(round(duration / dt))
    loop = jd.Loop(plant=p, sensor=jd.Identity(), estimator=jd.Passthrough(), controller=RelaxedProjection(p, P, gamma),
                   dt=dt, substeps=substeps, process_noise_std=noise_std, state_bound=jnp.asarray(state_bound))
    tail = min(n, int(round(1.0 / dt)))
    metrics = {"x": jd.metrics.Moments("x"), "u": jd.metrics.Moments("u"),
               "tail": jd.metrics.Window(jd.metrics.MaxAbs("x"), start=n - tail)}
    return jd.Rollout(loop, jd.Ball(jnp.zeros(p.n), radius), n, metrics=metrics)
