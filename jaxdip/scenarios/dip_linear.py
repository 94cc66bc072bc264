"""The linearised DIP estimation benchmark: ZOH at 1 ms, outputs xc, alpha, theta with white noise, process
noise on every state, a discrete LQR on the estimate. Shared by the estimator benchmarks (jaxdip.bench) and the
weighted-MHE tests, so both run exactly the same loop."""

from __future__ import annotations

import jax
import numpy as np

import jaxdip as jd

DT, SENSOR_STD, PROC_STD, X0_RADIUS = 1e-3, np.array([1e-4, 1e-3, 1e-3]), 2e-4, 0.01
C3 = np.eye(3, 6)  # outputs xc, alpha, theta


class LinearPlant(jd.DiscretePlant):
    """x_{k+1} = Phi x_k + W u_k on the DIP's state."""

    Phi: jax.Array = jd.param()
    W: jax.Array = jd.param()
    state_names = ("xc", "alpha", "theta", "xc_dot", "alpha_dot", "theta_dot")

    def step(self, x, u):
        return self.Phi @ x + self.W @ u


class LinearSensor(jd.Sensor):
    """y = C x + std * xi, the noise drawn from the period's sensor key itself."""

    C: jax.Array = jd.param()
    std: jax.Array = jd.param()

    def step(self, state, x, key, k):
        return state, self.C @ x + self.std * jax.random.normal(key, (self.C.shape[0],)), None


def problem():
    """(model, K, Q, R, P0): the ZOH model, its LQR gain, the true noise covariances, and P0 the covariance of
    the initial state (uniform in the ball of radius X0_RADIUS: r^2 / (d + 2) I)."""
    A, B = jd.linearize(jd.plants.DIP())
    model = jd.zoh(A, B, DT)
    K, _, _ = jd.control.dlqr(model.Phi, model.W, np.diag([10.0] * 3 + [0.1] * 3), np.eye(1))
    Q, R = PROC_STD**2 * np.eye(6), np.diag(SENSOR_STD**2)
    P0 = X0_RADIUS**2 / 8 * np.eye(6)
    return model, K, Q, R, P0


def loop(estimator, model, K) -> jd.Loop:
    """The closed loop around ``estimator``: linear plant with process noise, noisy outputs, LQR."""
    return jd.Loop(plant=LinearPlant(model.Phi, model.W), sensor=LinearSensor(C3, SENSOR_STD), estimator=estimator,
                   controller=jd.control.StateFeedback(K), dt=DT, substeps=1, process_noise_std=PROC_STD)
