"""Throughput of jaxdip's estimators on the linearised DIP (ZOH 1 ms, outputs xc, alpha, theta, LQR loop):
trajectory-steps per second and velocity RMS error of the KF, CPX (gamma = 150), the weighted MHE with the true
noise weights (N = 10) and the batch filter/smoother over recorded sequences.

    python -m jaxdip.bench.estimators [--seeds 128] [--steps 2000]

Not part of the test suite. ``jaxdip.bench.peers`` compares with dynamax and do-mpc on the same loop
(``dip_problem`` and ``dip_loop`` below).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.estimators import recorded
from jaxdip.estimators.weighted_mhe import WeightedMHE
from jaxdip.scenarios.dip_linear import C3, DT, SENSOR_STD, X0_RADIUS  # noqa: F401  (peers reads them here)
from jaxdip.scenarios.dip_linear import loop as dip_loop
from jaxdip.scenarios.dip_linear import problem as dip_problem


def _vel_err(s):
    return s.xhat[3:6] - s.x[3:6]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=128)
    ap.add_argument("--steps", type=int, default=2000)
    args = ap.parse_args()
    model, K, Q, R, P0 = dip_problem()
    estimators = {
        "kf": jd.estimators.KalmanFilter(model.Phi, model.W, C3, Q, R, P0),
        "cpx": jd.estimators.CPX(150.0, model, C3, jnp.zeros(6)),
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
    kf = jd.estimators.KalmanFilter(model.Phi, None, C3, Q, R, P0)
    for name, fn in (("offline filter", recorded.kalman_filter), ("offline smoother", recorded.rts_smoother)):
        f = jax.jit(jax.vmap(lambda y: fn(kf, y)))
        jax.block_until_ready(f(ys))
        t = time.perf_counter()
        jax.block_until_ready(f(ys))
        wall = time.perf_counter() - t
        print(f"{name:14s}: {n_ts / wall:10.3g} trajectory-steps/s ({1e9 * wall / n_ts:8.1f} ns each), "
              "with covariances and the log-likelihood")


if __name__ == "__main__":
    main()
