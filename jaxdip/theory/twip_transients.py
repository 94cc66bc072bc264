"""Transient figures of merit of the TWIP studies (Stumfoll §5.2 Fig. 5.5, §8.1.1 "15 s", §8.1.2 "5 deg").

* ``swing``: the open-loop TWIP (72)-(73), input 0 V, released at rest from theta0 next to the hanging
  equilibrium theta = 0 (phi = theta - pi = theta0 - pi), the check of Fig. 5.5. The only damping is the motors'
  back-EMF (the ke km terms), which acts on the wheels' speed.
* ``settling_time``: the first time after which |signal| stays within a band for the rest of the record.
* ``overshoot``: how far a signal that starts on one side of its target goes past it on the other side.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.plants import twip
from jaxdip.engine.integrate import rk4_zoh


def swing(theta0_deg: float = 10.0, duration: float = 20.0, dt: float = 0.01, substeps: int = 10,
          params: twip.TWIP | None = None):
    """(t, x) of the unforced TWIP from [0, 0, theta0 - pi, 0]; x = [x, x_dot, phi, phi_dot] per sample,
    phi = theta - pi (so theta = phi + pi, hanging at theta = 0)."""
    p = twip.TWIP() if params is None else params
    x0 = jnp.array([0.0, 0.0, math.radians(theta0_deg) - math.pi, 0.0])
    n = int(round(duration / dt))
    u = jnp.zeros(1)

    def step(x, _):
        x1 = rk4_zoh(twip.f, p, x, u, dt, substeps)
        return x1, x1

    _, xs = jax.lax.scan(step, x0, None, length=n)
    return np.arange(n + 1) * dt, np.vstack([np.asarray(x0)[None], np.asarray(xs)])


def theta_of(phi):
    """theta = phi + pi wrapped to (-pi, pi]: the angle from the hanging position."""
    return np.angle(np.exp(1j * (np.asarray(phi) + math.pi)))


def settling_time(t, signal, band: float) -> float:
    """First time after which |signal| <= band for the rest of the record (t[-1] + dt-free: inf if it ends out)."""
    s = np.abs(np.asarray(signal)) > band
    if s[-1]:
        return math.inf
    out = np.nonzero(s)[0]
    return float(t[0] if out.size == 0 else t[out[-1] + 1])


def overshoot(signal, target: float = 0.0) -> float:
    """max over the record of (target - signal) if the signal starts above the target, of (signal - target) if
    below; 0 if it never crosses."""
    s = np.asarray(signal) - target
    side = np.sign(s[0])
    return float(max(0.0, np.max(-side * s)))


def peaks(signal) -> np.ndarray:
    """Indices of the strict local maxima of |signal - its final value| (the swing's amplitude envelope)."""
    a = np.abs(np.asarray(signal) - np.asarray(signal)[-1])
    i = np.nonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:]))[0] + 1
    return i


def reach_time(t, X, bands) -> float:
    """First time at which every column of X is inside its band at once (inf if never)."""
    inside = np.all(np.abs(np.asarray(X)) <= np.asarray(bands), axis=1)
    i = np.nonzero(inside)[0]
    return float(t[i[0]]) if i.size else math.inf
