"""The DIP's measurements as on the Quanser laboratory system: three quadrature encoders (xc, alpha, theta).

The source documents say only that "encoders measure three variables" (paper §5, thesis §3.3); they give no
resolution. The defaults here come from Quanser's own documentation of the hardware, NOT from the seeds:

* pendulum angles: 1024-line optical encoders read in quadrature, 4096 counts per revolution, so one count is
  2 pi / 4096 = 1.534e-3 rad (0.088 deg) (Quanser IP02 / SRV02 and double-pendulum manuals);
* cart position: the IP02 cart encoder, also 4096 counts per revolution, on a pinion of radius 14.83 mm that
  runs on the rack, giving 2 pi 0.01483 / 4096 = 2.275e-5 m per count (the IP02 manual's 22.75 um/count).

Measurement noise: an encoder has no analogue noise, but the readings carry mechanical play and vibration of
the links and the cart; we add white Gaussian noise *before* quantisation (so the output stays a whole number of
counts), by default half a count per channel. Quantisation itself is the dominant error of the velocity
estimates: a difference quotient of an angle at 1 kHz has a resolution of 1.53 rad/s.
"""

from __future__ import annotations

import math
from typing import Sequence

import jax.numpy as jnp

from jaxdip.sim import sensors

from jaxdip._public import public_dir

__all__ = ["ENCODER_COUNTS_PER_REV", "ANGLE_QUANTUM", "CART_ENCODER_PINION_RADIUS", "CART_QUANTUM", "DEFAULT_QUANTA",
           "MEASURED", "output_matrix", "encoders"]
__dir__ = public_dir(globals())

ENCODER_COUNTS_PER_REV = 4096  # 1024 lines x 4 (quadrature)
ANGLE_QUANTUM = 2.0 * math.pi / ENCODER_COUNTS_PER_REV  # rad per count
CART_ENCODER_PINION_RADIUS = 0.01483  # m (IP02 position-encoder pinion)
CART_QUANTUM = 2.0 * math.pi * CART_ENCODER_PINION_RADIUS / ENCODER_COUNTS_PER_REV  # m per count, 2.275e-5
DEFAULT_QUANTA = (CART_QUANTUM, ANGLE_QUANTUM, ANGLE_QUANTUM)
MEASURED = ("xc", "alpha", "theta")


def output_matrix(state_names: Sequence[str], measured: Sequence[str] = MEASURED) -> jnp.ndarray:
    """C selecting the measured states by name (p x n)."""
    C = [[1.0 if s == m else 0.0 for s in state_names] for m in measured]
    missing = [m for m in measured if m not in state_names]
    if missing:
        raise KeyError(f"no state(s) {missing} in {tuple(state_names)}")
    return jnp.asarray(C, dtype=jnp.float64)


def encoders(dt: float, state_names: Sequence[str], quanta=DEFAULT_QUANTA, noise_counts=0.5,
             measured: Sequence[str] = MEASURED, straight_through: bool = False) -> sensors.LinearSensor:
    """The encoders as a ``sensors.LinearSensor``: quantised, with white noise of ``noise_counts`` counts (std).

    ``quanta`` (one per measured state, 0 disables quantisation of that channel) and ``noise_counts`` (scalar
    or one per channel) end up as the sensor's array fields, so they can be vmapped or differentiated; no walking
    bias.
    """
    q = jnp.broadcast_to(jnp.asarray(quanta, dtype=jnp.float64), (len(measured),))
    white = jnp.asarray(noise_counts, dtype=jnp.float64) * q
    return sensors.LinearSensor(output_matrix(state_names, measured), dt, white_std=white, quantum=q,
                                straight_through=straight_through)
