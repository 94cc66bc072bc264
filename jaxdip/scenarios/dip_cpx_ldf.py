"""The DIP stabilised by power-series control fed by CPX or by the low-pass derivative filter (paper §5 Table 1,
thesis §3.3 Table 3.2): the loop of the dip-cpx-ldf experiment and of the tune target ``cpx``.

Printed model at 1 kHz. The encoders measure xc, alpha, theta (quantised, with white noise,
``jaxdip.sim.dip_sensors``); the estimator gets (y_k, u_{k-1}); the power-series law (3.5) with Q on
[xc, alpha, theta, velocities] (the paper's diag(80, 300, 100, 0, 0, 0) is on [xc, theta, alpha], mapped here by
name) and R computes u_k; the plant receives u_k plus an input disturbance (a per-trial constant offset and white
noise, ``jaxdip.sim.disturbance``).

CPX is ``jaxdip.estimators.CPX`` on the ZOH discretisation of the model's linearisation at upright, x_hat_0 = 0
(as in the paper). What it hands the controller is, by default, its one-step model prediction (``Ahead``, see
``jaxdip.estimators.cpx``); ``cpx_output = "current"`` hands x^_k instead. Its ``gamma`` is a leaf, so a sweep or
a gradient over it reuses one compiled loop. The LDF hands the measured positions and the filtered derivatives.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import jaxdip as jd
from jaxdip.estimators import CPX, LDF, Ahead
from jaxdip.plants import dip
from jaxdip.plants.dip_friction import CartFriction
from jaxdip.sim import dip_sensors
from jaxdip.sim.actuators import Chain, Deadzone, InputBacklash
from jaxdip.sim.disturbance import InputDisturbance

INF = float("inf")
# the paper's Q = diag(80, 300, 100, 0, 0, 0) on [xc, theta, alpha], written on the state order
PAPER_Q = (80.0, 100.0, 300.0, 0.0, 0.0, 0.0)
PAPER_R = 0.5


def estimation_error(s: jd.Sample):
    """What the controller got minus the truth (module level: one compiled program for every build)."""
    return s.xhat - s.x


def gamma_leaf(r: jd.Rollout):
    """Where CPX's gamma sits in a rollout of this scenario (for ``monte_carlo(sweep=...)`` and tuning)."""
    e = r.loop.estimator
    return (e.inner if isinstance(e, Ahead) else e).gamma


@dataclasses.dataclass(frozen=True)
class DipCpxLdf:
    """The scenario's numbers. ``Q`` is the diagonal or the full 6 x 6 state weight on [xc, alpha, theta,
    velocities]; ``state_bound`` counts as divergence; the encoders quantise to ``encoder_quanta`` (xc in m,
    alpha and theta in rad) with white noise of ``noise_counts`` counts before rounding. ``straight_through``
    differentiates the quantiser as the identity (for tuning)."""

    variant: str = "printed"
    dt: float = 0.001
    substeps: int = 10
    duration: float = 6.5
    Q: Sequence = PAPER_Q
    R: float = PAPER_R
    cpx_gamma: float = 150.0
    cpx_output: str = "prediction"
    ldf_cart_cutoff: float = 100 * math.pi
    ldf_angle_cutoff: float = 20 * math.pi
    ldf_zeta: float = 0.9
    encoder_quanta: Sequence = dip_sensors.DEFAULT_QUANTA
    noise_counts: float = 0.5
    input_offset_std: float = 0.0
    input_noise_std: float = 1.0
    init_radius: float = 0.01
    state_bound: Sequence = (0.5, 0.7854, 0.7854, INF, INF, INF)
    tail: float = 1.0  # the last ``tail`` seconds decide "stabilised" (the ``tail`` metric)
    straight_through: bool = False
    cpx_weight: str = "sqrt_gamma"  # "printed": (3.7)'s I/gamma, i.e. the proximal weight gamma^2
    deadzone: Sequence = (0.0, 0.0)  # (d_minus, d_plus) of (160) on the applied input (V)
    backlash: float = 0.0  # half-width d of (161) on the applied input (V), slope 1
    cart_coulomb: float = 0.0  # Coulomb friction on the cart (N)
    coulomb_smoothing: float = 1e-3  # its sign smoothed as tanh(xc_dot / this) (m/s)

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.dt))

    def plant(self) -> dip.DIP:
        """The model every controller and estimator designs on."""
        return dip.DIP(variant=self.variant)

    def truth(self):
        """The simulated plant: the model, with Coulomb friction on the cart when ``cart_coulomb`` > 0."""
        p = self.plant()
        return CartFriction(p, self.cart_coulomb, self.coulomb_smoothing) if self.cart_coulomb > 0 else p

    def actuator(self):
        """The input disturbance, then (when set) the deadzone and the backlash."""
        stages = [InputDisturbance(self.input_offset_std, self.input_noise_std)]
        if tuple(self.deadzone) != (0.0, 0.0):
            stages.append(Deadzone(self.deadzone[0], self.deadzone[1]))
        if self.backlash > 0:
            stages.append(InputBacklash(jnp.ones(1), -self.backlash * jnp.ones(1), self.backlash * jnp.ones(1)))
        return stages[0] if len(stages) == 1 else Chain(*stages)

    def effective_gamma(self, gamma):
        """The proximal weight the configured gamma stands for under the ``cpx_weight`` reading."""
        return gamma**2 if self.cpx_weight == "printed" else gamma

    def weight(self) -> np.ndarray:
        Q = np.asarray(self.Q, dtype=np.float64)
        return np.diag(Q) if Q.ndim == 1 else Q

    def model(self, plant: Optional[dip.DIP] = None):
        """CPX's model (``Discrete``: ZOH of the linearisation at upright over dt) and output matrix, of the
        configured plant or of ``plant``."""
        plant = self.plant() if plant is None else plant
        return jd.zoh(*jd.linearize(plant), self.dt), dip_sensors.output_matrix(plant.state_names)

    def cpx(self, gamma=None, output: Optional[str] = None):
        """CPX at the configured gamma (through the ``cpx_weight`` reading), or at the proximal weight
        ``gamma`` when one is given."""
        model, C = self.model()
        g = self.effective_gamma(self.cpx_gamma) if gamma is None else gamma
        cpx = CPX(gamma=g, model=model, C=C, xhat0=jnp.zeros(6))
        return Ahead(cpx) if (output or self.cpx_output) == "prediction" else cpx

    def ldf(self) -> LDF:
        return LDF.dip(self.dt, self.ldf_cart_cutoff, self.ldf_angle_cutoff, self.ldf_zeta)

    def estimator(self, name: str):
        if name == "cpx":
            return self.cpx()
        if name == "ldf":
            return self.ldf()
        raise ValueError(f"estimator must be 'cpx' or 'ldf', got {name!r}")

    def loop(self, estimator) -> jd.Loop:
        """The closed loop around ``estimator`` (a name, or any estimator Module such as a ``jd.FanOut``)."""
        plant = self.plant()
        est = self.estimator(estimator) if isinstance(estimator, str) else estimator
        return jd.Loop(plant=self.truth(),
                       sensor=dip_sensors.encoders(self.dt, plant.state_names, self.encoder_quanta,
                                                   self.noise_counts, straight_through=self.straight_through),
                       estimator=est, controller=jd.control.PowerSeries.design(plant, self.weight(), self.R),
                       actuator=self.actuator(), dt=self.dt,
                       substeps=self.substeps, state_bound=jnp.asarray(self.state_bound))

    def metrics(self) -> dict:
        """Time moments of x and u, max |x| over the tail, RMS error of what the controller got."""
        n = self.steps
        tail = min(n, int(round(self.tail / self.dt)))
        return {"x": jd.metrics.Moments("x"), "u": jd.metrics.Moments("u"),
                "tail": jd.metrics.Window(jd.metrics.MaxAbs("x"), start=n - tail),
                "err": jd.metrics.RMS(estimation_error)}

    def rollout(self, estimator="cpx", save=None, save_every: int = 1) -> jd.Rollout:
        """One Monte Carlo trial: initial states uniform in the ball of ``init_radius`` around upright."""
        return jd.Rollout(self.loop(estimator), jd.Ball(jnp.zeros(6), self.init_radius), self.steps, save=save,
                          save_every=save_every, metrics=self.metrics())

    def gamma_criterion(self, plant: Optional[dip.DIP] = None) -> dict:
        """Prop. 1.4.3 for CPX on this model (or on ``plant``) at this period
        (``jaxdip.theory.mhe.cpx_gamma_criterion``)."""
        from jaxdip.theory.mhe import cpx_gamma_criterion

        model, C = self.model(plant)
        g, K, lam = cpx_gamma_criterion(model.Phi, model.Phi_inv, C)
        return {"gamma": float(g), "K_max": float(K), "lambda_min": float(lam)}


def with_gamma(r: jd.Rollout, gamma) -> jd.Rollout:
    return eqx.tree_at(gamma_leaf, r, jnp.asarray(gamma, dtype=jnp.float64))
