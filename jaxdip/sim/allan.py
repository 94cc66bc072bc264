"""Allan variance of a sampled sensor signal, and the closed forms of the noise models the sensors simulate.

The overlapping Allan variance of a rate signal y_k sampled every dt, at cluster time tau = m dt, is

    AVAR(tau) = 1 / (2 (N - 2m + 1)) sum_k (ybar_{k+m} - ybar_k)^2,   ybar_k = mean of y_k .. y_{k+m-1},

computed here from cumulative sums (O(N) per tau). Closed forms used to check simulated sensors (Stumfoll
Table 7.1 / Fig. 7.1):

* white noise of variance s^2 per sample: AVAR(m dt) = s^2 / m (the law sigma^2 / tau with sigma^2 = s^2 dt);
* first-order Gauss-Markov bias b' = -b / T + w, E[w(t) w(s)] = q delta(t - s) (stationary variance q T / 2):
  AVAR(tau) = q T^2 / tau [1 - T / (2 tau) (3 - 4 e^{-tau/T} + e^{-2 tau/T})] for averages over continuous time;
  a sensor *samples* b, and for samples the exact law follows from the autocovariance R(k) of any stationary
  sequence (``avar_stationary``): with ybar_1, ybar_2 adjacent means of m samples,
      AVAR(m) = Var(ybar) - Cov(ybar_1, ybar_2)
              = m^-2 sum_{|k|<m} (m - |k|) (R(k) - R(m + k)),
  which for the sampled Gauss-Markov bias (R(k) = q T / 2 a^|k|, a = e^{-dt/T}) differs from the continuous
  form by O(dt / tau) (a factor 3/2 at m = 1);
* a rate obtained by differencing a quantised position (quantum Q) that moves across many quanta: the
  quantisation errors e_k are close to independent U(-Q/2, Q/2), the cluster mean is (e_{k+m} - e_k) / tau plus
  the true rate, so AVAR(tau) = (1/2) E[(e_{k+2m} - 2 e_{k+m} + e_k)^2] / tau^2 = Q^2 / (4 tau^2).
"""

from __future__ import annotations

import math

import numpy as np


from jaxdip._public import public_dir

__all__ = ["allan_variance", "avar_white", "avar_gauss_markov", "avar_differenced_quantised", "avar_stationary",
           "avar_sampled_white_gauss_markov"]
__dir__ = public_dir(globals())


def allan_variance(y, m) -> np.ndarray:
    """Overlapping Allan variance of ``y`` (1-D, one sample per period) at the cluster sizes ``m`` (ints >= 1,
    each at most (len(y) - 1) / 2); returns one value per entry of ``m``."""
    y = np.asarray(y, dtype=np.float64)
    ms = np.atleast_1d(np.asarray(m))
    if y.ndim != 1:
        raise ValueError("y must be one-dimensional")
    if np.any(ms < 1) or np.any(2 * ms > y.size - 1):
        raise ValueError(f"cluster sizes must lie in [1, (len(y) - 1) / 2] = [1, {(y.size - 1) // 2}]")
    c = np.concatenate([[0.0], np.cumsum(y - y.mean())])  # centring keeps the sums' rounding small
    out = []
    for mi in ms.astype(int):
        means = (c[mi:] - c[:-mi]) / mi  # ybar_k for k = 0 .. N - m
        d = means[mi:] - means[:-mi]
        out.append(0.5 * np.mean(d * d))
    return np.asarray(out)


def avar_white(var_per_sample: float, m) -> np.ndarray:
    """White noise of variance ``var_per_sample`` per sample, at cluster sizes ``m``."""
    return var_per_sample / np.asarray(m, dtype=np.float64)


def avar_gauss_markov(q: float, T: float, tau) -> np.ndarray:
    """First-order Gauss-Markov process of driving intensity ``q`` (units^2 / s) and time constant ``T`` (s)."""
    tau = np.asarray(tau, dtype=np.float64)
    r = tau / T
    return q * T**2 / tau * (1.0 - (3.0 - 4.0 * np.exp(-r) + np.exp(-2.0 * r)) / (2.0 * r))


def avar_differenced_quantised(quantum: float, tau) -> np.ndarray:
    """Rate from differences of a position quantised to ``quantum``, the position sweeping many quanta."""
    return quantum**2 / (4.0 * np.asarray(tau, dtype=np.float64) ** 2)


def avar_stationary(R, m) -> np.ndarray:
    """Exact Allan variance at cluster sizes ``m`` of a stationary sequence with autocovariance ``R`` (a
    function of an integer-lag array, even in the lag)."""
    out = []
    for mi in np.atleast_1d(np.asarray(m)).astype(int):
        k = np.arange(-(mi - 1), mi)
        w = (mi - np.abs(k)).astype(np.float64)
        out.append(float(np.sum(w * (R(k) - R(mi + k))) / mi**2))
    return np.asarray(out)


def avar_sampled_white_gauss_markov(white_var: float, q: float, T: float, dt: float, m) -> np.ndarray:
    """White noise of variance ``white_var`` per sample plus a Gauss-Markov bias (intensity ``q``, time
    constant ``T``) sampled every ``dt``: the exact Allan variance of the samples at cluster sizes ``m``."""
    a = math.exp(-dt / T)
    R = lambda k: white_var * (k == 0) + 0.5 * q * T * a ** np.abs(k)  # noqa: E731
    return avar_stationary(R, m)
