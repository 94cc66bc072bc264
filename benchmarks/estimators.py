"""Throughput of jaxdip's estimators on the linearised DIP (ZOH 1 ms, outputs xc, alpha, theta, LQR loop):
trajectory-steps per second and velocity RMS error of the KF, CPX (gamma = 150), the weighted MHE with the true
noise weights (N = 10) and the batch filter/smoother over recorded sequences.

    python benchmarks/estimators.py [--seeds 128] [--steps 2000]

Not part of the test suite. ``benchmarks/peers.py`` compares with dynamax and do-mpc on the same loop
(``dip_problem`` and ``dip_loop`` below).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.estimators import lgssm
from jaxdip.estimators.weighted_mhe import WeightedMHE

DT, SENSOR_STD, PROC_STD, X0_RADIUS = 1e-3, np.array([1e-4, 1e-3, 1e-3]), 2e-4, 0.01
C3 = np.eye(3, 6)


class LinearPlant(jd.DiscretePlant):
    Phi: jax.Array = jd.param()
    W: jax.Array = jd.param()
    state_names = ("xc", "alpha", "theta", "xc_dot", "alpha_dot", "theta_dot")

    def step(self, x, u):
        return self.Phi @ x + self.W @ u


class LinearSensor(jd.Sensor):
    C: jax.Array = jd.param()
    std: jax.Array = jd.param()

    def step(self, state, x, key, k):
        return state, self.C @ x + self.std * jax.random.normal(key, (self.C.shape[0],)), None


def _vel_err(s):
    return s.xhat[3:6] - s.x[3:6]


def dip_problem():
    """The linearised DIP (ZOH 1 ms) with its LQR gain and the true noise covariances: (model, K, Q, R, P0).
    P0 is the covariance of the initial state (uniform in the ball of radius X0_RADIUS: r^2 / (d + 2) I)."""
    A, B = jd.linearize(jd.plants.DIP())
    model = jd.zoh(A, B, DT)
    K, _, _ = jd.control.dlqr(model.Phi, model.W, np.diag([10.0] * 3 + [0.1] * 3), np.eye(1))
    Q, R = PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2)
    P0 = X0_RADIUS**2 / 8 * np.eye(6)
    return model, K, Q, R, P0


def dip_loop(estimator, model, K) -> jd.Loop:
    """The closed loop: linear plant with process noise, outputs xc, alpha, theta with sensor noise, LQR."""
    return jd.Loop(plant=LinearPlant(model.Phi, model.W), sensor=LinearSensor(C3, SENSOR_STD), estimator=estimator,
                   controller=jd.control.StateFeedback(K), dt=DT, substeps=1, process_noise_std=PROC_STD)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=128)
    ap.add_argument("--steps", type=int, default=2000)
    args = ap.parse_args()
    model, K, Q, R, P0 = dip_problem()
    estimators = {
        "kf": jd.estimators.KalmanFilter(model.Phi, model.W, C3, Q, R, P0),
        "cpx": jd.estimators.CPX(150.0, model, C3, jnp.zeros(6), output="current"),
        "wmhe_n10": WeightedMHE.from_noise(model, C3, Q, R, N=10),
    }
    n_ts = args.seeds * args.steps
    print(f"{args.seeds} seeds x {args.steps} steps, device {jax.devices()[0].platform}")
    for name, est in estimators.items():
        ro = jd.Rollout(dip_loop(est, model, K), jd.Ball(jnp.zeros(6), X0_RADIUS), args.steps, metrics=jd.metrics.RMS(_vel_err))
        jax.block_until_ready(jd.monte_carlo(ro, 0, args.seeds))  # compile
        t = time.perf_counter()
        out = jax.block_until_ready(jd.monte_carlo(ro, 0, args.seeds))
        wall = time.perf_counter() - t
        rms = float(np.sqrt(np.mean(np.sum(np.asarray(out.metrics) ** 2, axis=1))))
        print(f"{name:10s} closed loop: {n_ts / wall:10.3g} trajectory-steps/s ({1e9 * wall / n_ts:8.1f} ns each), "
              f"velocity RMS {rms:.4g}")
    # the batch filter and smoother over recorded sequences (outputs of the open-loop model, for scale only)
    ys = np.random.default_rng(0).normal(size=(args.seeds, args.steps, 3)) * SENSOR_STD
    for name, fn in (("lgssm filter", lgssm.kalman_filter), ("lgssm smoother", lgssm.rts_smoother)):
        f = jax.jit(jax.vmap(lambda y: fn(y, jnp.zeros(6), P0, Q, R, Phi=model.Phi, C=C3)))
        jax.block_until_ready(f(ys))
        t = time.perf_counter()
        jax.block_until_ready(f(ys))
        wall = time.perf_counter() - t
        print(f"{name:14s}: {n_ts / wall:10.3g} trajectory-steps/s ({1e9 * wall / n_ts:8.1f} ns each), "
              "with covariances and the log-likelihood")


if __name__ == "__main__":
    main()
