"""Functions a loop calls many times while it is traced are traced once per structure and shapes, and give the
same bits as a direct trace: a plant's right-hand side (``engine.roles.rhs``, four calls per RK4 step and more
in every linearisation), the linearised discretisation of the EKF and the CPX (``estimators.linearized``), and a
continuous observer's right-hand side (``estimators.continuous``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine.integrate import rk4_zoh
from jaxdip.engine.roles import linearize, rhs
from jaxdip.estimators import continuous, homd, linearized
from jaxdip.plants.dip import DIP

CALLS = {"n": 0}


class CountingDIP(DIP):
    def vector_field(self, x, u):
        CALLS["n"] += 1
        return super().vector_field(x, u)


def _state():
    return jnp.array([0.01, 0.05, -0.03, 0.0, 0.1, -0.2]), jnp.array([0.3])


def test_a_plants_right_hand_side_is_traced_once_for_a_period_and_its_jacobians():
    plant, (x, u) = CountingDIP(), _state()
    CALLS["n"] = 0
    jax.jit(lambda x, u: plant.period(x, u, 0.01, 4))(x, u)
    assert CALLS["n"] == 1  # a direct call traced it four times: once per RK4 stage
    linearize(plant, x, u)
    jax.jit(jax.vmap(lambda x: plant.period(x, u, 0.01, 4)))(jnp.stack([x, 2 * x]))
    assert CALLS["n"] == 1  # the Jacobians and the batch transform the jaxpr already traced
    jax.jit(lambda x, u: CountingDIP(trig="vectorised").period(x, u, 0.01, 4))(x, u)
    assert CALLS["n"] == 2  # another plant structure (a static field): traced again


def test_a_period_through_rhs_equals_the_direct_trace_bit_for_bit():
    plant, (x, u) = DIP(), _state()
    xs = x + 0.01 * jnp.arange(5.0)[:, None]
    # the plant an argument in both, as in a loop (closed over, XLA would fold its parameters as constants)
    step = jax.jit(jax.vmap(lambda x, p: rk4_zoh(rhs, p, x, u, 0.01, 10), in_axes=(0, None)))
    direct = jax.jit(jax.vmap(lambda x, p: rk4_zoh(lambda p, x, u: p.vector_field(x, u), p, x, u, 0.01, 10),
                              in_axes=(0, None)))
    assert np.array_equal(np.asarray(step(xs, plant)), np.asarray(direct(xs, plant)))
    A, B = linearize(plant, x, u)
    A_direct = jax.jit(lambda p, x, u: jax.jacfwd(lambda x: p.vector_field(x, u))(x))(plant, x, u)
    assert np.array_equal(np.asarray(A), np.asarray(A_direct))


def _counting_f(plant, x, u):
    CALLS["n"] += 1
    return plant.vector_field(x, u)


def test_the_linearised_discretisation_is_traced_once_and_equals_the_direct_trace():
    plant, (x, u) = DIP(), _state()
    CALLS["n"] = 0
    one = jax.jit(lambda x: linearized.local_model(_counting_f, plant, x, u, 0.01).Phi)
    other = jax.jit(lambda x: 2.0 * linearized.local_model(_counting_f, plant, x, u, 0.01).W)
    one(x)
    first = CALLS["n"]
    other(x)
    assert first > 0 and CALLS["n"] == first  # the second loop takes the first one's trace
    for field in ("Phi", "Phi_inv", "W", "b"):
        got = jax.jit(lambda x: getattr(linearized.local_model(rhs, plant, x, u, 0.01), field))(x)
        direct = jax.jit(lambda x: getattr(linearized._local_model.__wrapped__(rhs, plant, x, u, 0.01, True, 24),
                                           field))(x)
        assert np.array_equal(np.asarray(got), np.asarray(direct)), field


def _counting_homd_rhs(params, xi, y, u):
    CALLS["n"] += 1
    return homd.rwp_homd_rhs(params, xi, y, u)


class CountingHOMD(homd.HOMDObserver):
    rhs = staticmethod(_counting_homd_rhs)


def test_a_continuous_observers_right_hand_side_is_traced_once_and_gives_the_direct_bits():
    obs = CountingHOMD.build(0.002, substeps=3)
    y0, y1, u = jnp.array([0.1, 2.0]), jnp.array([0.11, 2.3]), jnp.array([0.05])
    state = (jnp.array([0.1, 0.2, 2.0, 1.0]), y0)
    CALLS["n"] = 0
    out = jax.jit(lambda s, y: obs.step(s, y, u, None, 3))(state, y1)
    assert CALLS["n"] == 1  # four RK4 stages, one trace
    xi, y_prev = state
    direct = jax.jit(lambda xi: continuous.integrate_interval(homd.rwp_homd_rhs, obs, xi, y_prev, y1, u, obs.dt,
                                                              obs.substeps, obs.hold))(xi)
    assert np.array_equal(np.asarray(out[2]), np.asarray(direct))
