"""The Lorenz MHE comparison (thesis §1.6) as one engine loop: CPX, SCPX and two EKFs on identical noise.

Data: the Lorenz system integrated with RK4 (``substeps`` per sample), sampled every h; y_k = C x_k + eps_k
with C measuring (yL, zL), eps ~ N(0, sigma_eps^2 I); after every sample the state gets eta_k ~
N(0, sigma_eta^2 I). The truth starts at x0_mean + x0_std N(0, I); every estimator starts from the same
xhat_0 = x_0 + init_error_std N(0, I) (``InitialError``; the EKFs' P_0 = init_error_std^2 I).

The four estimators sit in one ``FanOut``. CPX and SCPX hand out the model prediction of the next state
(``Ahead``); they are wrapped in ``Delayed`` so that their output at sample k is the prediction of x_k made at k - 1 (the
thesis's xtilde_{k+2} = Phi xhat_{k+1} compared with the state it predicts), and their current estimates
xhat_k come out as ``aux.xhat``. The EKFs' outputs are their filtered estimates x+_k. Nothing is controlled
(``ConstantInput`` of zero); the EKF is the nominal driver of the FanOut.

``alignment`` picks the time alignment the four are scored on:
  "mixed"       (default, as above) CPX/SCPX: the delayed prediction of x_k; EKFs: the filtered x+_k;
  "filtered"    every method's estimate of x_k from y_0 .. y_k: CPX/SCPX their current xhat_k, EKFs x+_k;
  "prediction"  every method's one-step prediction of x_k made at k - 1: CPX/SCPX as in "mixed", EKFs their
                prior x-_k (``Prior``).
The estimators compute the same numbers in every alignment; only what is compared with x_k changes.

Random streams (the experiment's convention, kept by ``MHEKeys``): trial key sk; x0 from fold_in(sk, 0), the
common initial estimate from fold_in(sk, 1), and at sample k, kk = fold_in(fold_in(sk, 2), k) split in two for
the measurement and the state noise.
"""

from __future__ import annotations

from typing import Optional, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.control.feedback import ConstantInput
from jaxdip.engine import Gaussian, KeySchedule, Loop, Rollout, param
from jaxdip.engine.metrics import Reducer
from jaxdip.estimators.cpx import LinearizedCPX
from jaxdip.estimators.kf import ExtendedKalmanFilter
from jaxdip.estimators.ukf import UnscentedKalmanFilter
from jaxdip.estimators.wrappers import Ahead, Delayed, InitialError, Prior
from jaxdip.engine.roles import FanOut
from jaxdip.plants import lorenz
from jaxdip.plants.lorenz import Lorenz
from jaxdip.sim.sensors import LinearSensor

METHODS = ("cpx", "scpx", "ekf", "ekf2")
PREDICTORS = ("cpx", "scpx")  # compared through their delayed prediction; their current estimate is aux
ALIGNMENTS = ("mixed", "filtered", "prediction")


class MHEKeys(KeySchedule):
    """Every init gets fold_in(sk, 1); sample k's key kk = fold_in(fold_in(sk, 2), k) goes to the sensor (which
    draws from split(kk)[0]) and the estimators, split(kk)[1] to the state noise."""

    def init(self, key):
        k = jax.random.fold_in(key, 1)
        return (k, k, k, k)

    def period(self, base, k):
        kk = jax.random.fold_in(base, k)
        _, k_eta = jax.random.split(kk)
        return (kk, kk, kk, kk, k_eta)


def _safe(a):
    return jnp.where(jnp.isfinite(a), a, 0.0)


class TrackingErrors(Reducer):
    """Per estimator (``FanOut`` member) until it diverges: sums of ||x_k - xhat_k|| and |x_c,k - xhat_c,k|
    (c = ``component``), the latter also where |x_c,k| > ``threshold`` (extrema), and for ``current`` members
    the same two sums of their aux (their current estimates), weighted by that member's divergence flag.
    A member diverges for good once its error norm is non-finite or above ``bound``. ``finalize`` returns the
    sums and counts (per-trial averages are sums / counts)."""

    names: tuple = eqx.field(static=True)
    current: tuple = eqx.field(static=True)
    threshold: jax.Array = param()
    bound: jax.Array = param()
    component: int = eqx.field(default=0, static=True)

    def init(self, template):
        m, c = len(self.names), len(self.current)
        fl = template.x.dtype  # the loop's
        z, zc, zi = jnp.zeros(m, fl), jnp.zeros(c, fl), jnp.zeros(m, jnp.int32)
        return {"norm": z, "xl": z, "xl_ext": z, "norm_cur": zc, "xl_cur": zc, "n": zi, "n_ext": zi,
                "diverged": jnp.zeros(m, bool)}

    def update(self, s, sample):
        est = sample.aux.estimator
        x = sample.x
        err = jnp.stack([est.xhat[n] for n in self.names]) - x
        norm = jnp.sqrt(jnp.sum(err**2, axis=1))
        xl = jnp.abs(err[:, self.component])
        cur = jnp.stack([est.aux[n].xhat for n in self.current]) - x if self.current else jnp.zeros((0, x.shape[0]))
        norm_cur = jnp.sqrt(jnp.sum(cur**2, axis=1))
        xl_cur = jnp.abs(cur[:, self.component])
        bad = ~jnp.isfinite(norm) | (norm > self.bound)
        diverged = s["diverged"] | bad
        w = (~diverged).astype(norm.dtype)
        ext = (jnp.abs(x[self.component]) > self.threshold) & ~diverged
        wc = w[jnp.asarray([self.names.index(n) for n in self.current], dtype=int)]
        return {
            "norm": s["norm"] + w * _safe(norm),
            "xl": s["xl"] + w * _safe(xl),
            "xl_ext": s["xl_ext"] + jnp.where(ext, _safe(xl), 0.0),
            "norm_cur": s["norm_cur"] + wc * _safe(norm_cur),
            "xl_cur": s["xl_cur"] + wc * _safe(xl_cur),
            "n": s["n"] + (~diverged).astype(jnp.int32),
            "n_ext": s["n_ext"] + ext.astype(jnp.int32),
            "diverged": diverged,
        }

    def finalize(self, s):
        return s


def record_xl(sample):
    """xL and every method's estimate of it (the figure's curves)."""
    xh = sample.aux.estimator.xhat
    return jnp.stack([sample.x[0]] + [xh[m][0] for m in METHODS])


def build(*, h: float = 0.001, steps: int, substeps: int = 1, sigma_eps: float = 5.0, sigma_eta: float = 0.1,
          x0_mean: Sequence[float] = (-8.0, 7.0, 27.0), x0_std: float = 1.0, init_error_std: float = 1.0,
          cpx_gamma: float = 0.5, scpx_gamma: float = 50.0, scpx_p: int = 2, ekf_sigma_eta: float = 0.1,
          ekf_sigma_eps: float = 5.0, ekf2_sigma_eta: float = 0.005, ekf2_sigma_eps: float = 10.0,
          extrema_threshold: float = 15.0, divergence_bound: float = 1000.0, expm_squarings: int = 3,
          save_every: Optional[int] = None, alignment: str = "mixed", ukf: bool = False) -> Rollout:
    """One trial of the comparison: metrics ``{"errors": TrackingErrors}``; with ``save_every``, ``record_xl``
    every ``save_every`` samples (``steps`` must be a multiple). All noise levels are standard deviations per
    sample (the EKFs' Q = ekf_sigma_eta^2 I, R = ekf_sigma_eps^2 I). ``alignment``: see the module docstring;
    the predictors' current estimates are ``TrackingErrors``' ``current`` sums except under "filtered", where
    they are the compared estimates themselves. ``ukf``: one more ``FanOut`` member "ukf", an unscented filter
    with the EKF's noise levels on the RK4 map over h (for a record of one trial; no metric reads it, and the
    other members' numbers are unchanged: every member gets the same keys)."""
    if alignment not in ALIGNMENTS:
        raise ValueError(f"alignment must be one of {ALIGNMENTS}, got {alignment!r}")
    plant = Lorenz()
    Cm = lorenz.output_matrix()
    z3 = jnp.zeros(3)
    P0 = init_error_std**2 * jnp.eye(3)

    def start(e):
        return InitialError(e, init_error_std)

    def cpx(gamma, keep):
        e = LinearizedCPX(gamma, plant, Cm, z3, h=h, keep=keep, expm_squarings=expm_squarings)
        return start(e if alignment == "filtered" else Delayed(Ahead(e)))

    def ekf(s_eta, s_eps):
        e = ExtendedKalmanFilter(s_eta**2 * jnp.eye(3), s_eps**2 * jnp.eye(2), P0, z3, model=plant, dt=h, C=Cm,
                                 expm_squarings=expm_squarings)
        return start(Prior(e) if alignment == "prediction" else e)

    members = {"cpx": cpx(cpx_gamma, None), "scpx": cpx(scpx_gamma, scpx_p),
               "ekf": ekf(ekf_sigma_eta, ekf_sigma_eps), "ekf2": ekf(ekf2_sigma_eta, ekf2_sigma_eps)}
    if ukf:
        members["ukf"] = start(UnscentedKalmanFilter(
            lambda x, u: plant.period(x, u, h, 1), lambda x: Cm @ x, ekf_sigma_eta**2 * jnp.eye(3),
            ekf_sigma_eps**2 * jnp.eye(2), P0, z3))
    estimators = FanOut(members, drive="ekf")
    loop = Loop(plant, LinearSensor(Cm, h, white_std=sigma_eps), estimators,
                ConstantInput(jnp.zeros(1)), dt=h, substeps=substeps, process_noise_std=sigma_eta, keys=MHEKeys())
    current = () if alignment == "filtered" else PREDICTORS
    metrics = {"errors": TrackingErrors(METHODS, current, extrema_threshold, divergence_bound)}
    x0 = Gaussian(jnp.asarray(x0_mean, dtype=jnp.float64), x0_std)
    if save_every is None:
        return Rollout(loop, x0, steps, metrics=metrics)
    return Rollout(loop, x0, steps, save=record_xl, save_every=save_every, metrics=metrics)


def gamma_of(name: str):
    """``where`` of the proximal weight of ``cpx`` or ``scpx`` in a rollout from ``build`` (for sweeps and
    gradients: ``eqx.tree_at(gamma_of("cpx"), rollout, g)``)."""
    def where(r):
        e = r.loop.estimator.estimators[name].inner
        while not isinstance(e, LinearizedCPX):
            e = e.inner
        return e.gamma

    return where
