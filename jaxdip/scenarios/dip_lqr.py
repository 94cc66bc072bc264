"""The DIP under continuous LQR held over the control period, noisy full-state measurements (thesis §3.2)."""

from __future__ import annotations

from typing import Sequence

import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.plants import dip

INF = float("inf")
TABLE_3_1_Q = (30.0, 350.0, 100.0, 0.0, 0.0, 0.0)  # on [xc, alpha, theta, xc_dot, alpha_dot, theta_dot]


def angles(sample):
    """What the band figure needs from each recorded period: alpha and theta."""
    return sample.x[1:3]


def dip_lqr(*, variant: str = "printed", dt: float = 0.001, substeps: int = 10, duration: float = 6.5,
            Q: Sequence = TABLE_3_1_Q, R: float = 0.1,
            noise_std: Sequence[float] = (1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2), init_radius: float = 0.05,
            state_bound: Sequence[float] = (1.0, 1.5708, 1.5708, INF, INF, INF), tail: float = 1.0,
            record_every: int | None = 10, trig: str = "vectorised", noise_draw: str = "float32") -> jd.Rollout:
    """One Monte Carlo trial: the loop, initial states uniform in a ball around upright, the angles recorded
    every ``record_every`` periods (None: nothing), and the metrics: moments of x and u, and max |x| over the
    last ``tail`` seconds (what decides "stabilised").

    ``trig`` is the DIP's (``"vectorised"``: sin and cos within 3 ulp of the C library's, in vectorised
    operations) and ``noise_draw`` the dtype the sensor draws its normals in before the cast to the loop's
    (``"float32"``: another stream that passes the same statistical checks; ``"loop"``: the loop's own dtype).
    This loop only evaluates the plant and draws noise, so the two are most of its period: together about 2x
    faster on a CPU. ``trig="library", noise_draw="loop"`` is the loop as it ran until 2026-11-26, for its
    numbers (docs/performance.md)."""
    plant = dip.DIP(variant=variant, trig=trig)
    Qm = np.asarray(Q, dtype=np.float64)
    Qm = np.diag(Qm) if Qm.ndim == 1 else Qm
    K, _, _ = jd.control.lqr(*jd.linearize(plant), Qm, R)
    n_steps = int(round(duration / dt))
    sensor = jd.sensors.WhiteNoise(noise_std, draw_dtype=None if noise_draw == "loop" else noise_draw)
    loop = jd.Loop(plant=plant, sensor=sensor, estimator=jd.Passthrough(),
                   controller=jd.control.StateFeedback(K), dt=dt, substeps=substeps, state_bound=state_bound)
    n_tail = min(n_steps, int(round(tail / dt)))
    metrics = {"x": jd.metrics.Moments("x"), "u": jd.metrics.Moments("u"),
               "tail": jd.metrics.Window(jd.metrics.MaxAbs("x"), start=n_steps - n_tail)}
    if record_every is None:
        return jd.Rollout(loop, jd.Ball(jnp.zeros(6), init_radius), n_steps, metrics=metrics)
    return jd.Rollout(loop, jd.Ball(jnp.zeros(6), init_radius), n_steps, save=angles, save_every=record_every,
                      metrics=metrics)
