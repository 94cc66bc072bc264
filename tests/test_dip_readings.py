"""The readings of the DIP fidelity study: the input backlash and the actuator chain against a plain NumPy loop,
Coulomb friction on the cart against the energy balance, the printed (3.7) against a NumPy least-squares solve,
and the new config keys' validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip import config as C
from jaxdip.estimators.proximal import prox_from_qr, qr_factor
from experiments.dip_cpx_ldf import DipCpxLdfConfig
from jaxdip.plants import dip
from jaxdip.plants.dip_friction import CartFriction
from jaxdip.scenarios import dip_cpx_ldf as S
from jaxdip.sim.actuators import Chain, Deadzone, InputBacklash


def _numpy_backlash(u_seq, d_minus, d_plus, m=1.0):
    """The standard backlash: the output follows m (u - d) on the side the input pushes, else holds."""
    psi, u_prev, out = 0.0, 0.0, []
    for u in u_seq:
        if u > u_prev and psi <= m * (u - d_plus):
            psi = m * (u - d_plus)
        elif u < u_prev and psi >= m * (u - d_minus):
            psi = m * (u - d_minus)
        out.append(psi)
        u_prev = u
    return np.array(out)


def _run_actuator(act, u_seq):
    st = act.init(jax.random.PRNGKey(0), jnp.zeros(6))
    out = []
    for k, u in enumerate(u_seq):
        st, ua, _ = act.step(st, jnp.array([u]), jax.random.PRNGKey(k), k)
        out.append(float(ua[0]))
    return np.array(out)


def test_input_backlash_and_chain_match_numpy():
    rng = np.random.default_rng(0)
    u = np.cumsum(rng.normal(0, 0.3, 200))
    got = _run_actuator(InputBacklash(jnp.ones(1), -0.4 * jnp.ones(1), 0.4 * jnp.ones(1)), u)
    np.testing.assert_allclose(got, _numpy_backlash(u, -0.4, 0.4), atol=1e-15)
    # a deadzone then the backlash: the NumPy deadzone fed into the NumPy backlash
    dz = np.where((u >= -0.5) & (u < 0.5), 0.0, u)
    chain = Chain(Deadzone(-0.5, 0.5), InputBacklash(jnp.ones(1), -0.4 * jnp.ones(1), 0.4 * jnp.ones(1)))
    np.testing.assert_allclose(_run_actuator(chain, u), _numpy_backlash(dz, -0.4, 0.4), atol=1e-15)
    # zero width passes the input
    np.testing.assert_allclose(_run_actuator(InputBacklash(jnp.ones(1), jnp.zeros(1), jnp.zeros(1)), u), u)


@pytest.mark.parametrize("variant", ["lagrangian"])
def test_cart_friction_removes_power_F_times_velocity(variant):
    """On the energy-conserving model dE/dt = sum_i Q_i qdot_i; friction adds -F tanh(xc_dot / v) xc_dot to it,
    whatever the voltage conversion inside the wrapper."""
    p = dip.DIP(variant=variant)
    F, v = 1.7, 1e-3
    wrapped = CartFriction(p, F, v)
    dE = jax.grad(p.energy)
    rng = np.random.default_rng(1)
    for _ in range(5):
        x = jnp.asarray(rng.normal(0, [0.1, 0.2, 0.2, 0.01, 0.5, 0.5]))
        u = jnp.array([rng.normal()])
        diff = dE(x) @ wrapped.vector_field(x, u) - dE(x) @ p.vector_field(x, u)
        np.testing.assert_allclose(diff, -F * np.tanh(x[3] / v) * x[3], rtol=1e-9, atol=1e-12)


def test_printed_37_is_least_squares_with_I_over_gamma():
    """cpx_weight = "printed": CPX's proximal point is the least-squares solution of (3.7) with the top block
    I/gamma as printed (NumPy lstsq of the stacked system), not the one with I/sqrt(gamma)."""
    gamma = 150.0
    sc = S.DipCpxLdf(cpx_weight="printed", cpx_gamma=gamma)
    est = sc.cpx(output="current")  # the CPX itself (by default it is wrapped in Ahead)
    model, Cm = sc.model()
    G = np.vstack([Cm @ np.asarray(model.Phi_inv), Cm, Cm @ np.asarray(model.Phi)])
    rng = np.random.default_rng(2)
    xhat, q = rng.normal(size=6), rng.normal(size=9)
    H = np.vstack([np.eye(6) / gamma, G])
    want = np.linalg.lstsq(H, np.concatenate([xhat / gamma, q]), rcond=None)[0]
    QT, R = qr_factor(jnp.asarray(G), est.gamma)
    got = np.asarray(prox_from_qr(QT, R, jnp.asarray(q), jnp.asarray(xhat), est.gamma))
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-9)
    # the default reading is the I/sqrt(gamma) system
    H2 = np.vstack([np.eye(6) / np.sqrt(gamma), G])
    want2 = np.linalg.lstsq(H2, np.concatenate([xhat / np.sqrt(gamma), q]), rcond=None)[0]
    g2 = S.DipCpxLdf(cpx_gamma=gamma).cpx(output="current").gamma
    QT, R = qr_factor(jnp.asarray(G), g2)
    np.testing.assert_allclose(np.asarray(prox_from_qr(QT, R, jnp.asarray(q), jnp.asarray(xhat), g2)), want2,
                               rtol=1e-7, atol=1e-9)
    assert not np.allclose(want, want2, rtol=1e-3)


def test_default_loop_is_unchanged_and_readings_build():
    sc = S.DipCpxLdf()
    assert isinstance(sc.truth(), dip.DIP)
    assert type(sc.actuator()).__name__ == "InputDisturbance"
    sc2 = S.DipCpxLdf(deadzone=(-0.3, 0.3), backlash=0.2, cart_coulomb=1.0)
    assert isinstance(sc2.truth(), CartFriction)
    assert [type(s).__name__ for s in sc2.actuator().stages] == ["InputDisturbance", "Deadzone", "InputBacklash"]


@pytest.mark.parametrize("key,value", [("deadzone", [0.2, 0.5]), ("deadzone", [0.0]), ("backlash", -1.0),
                                       ("cart_coulomb", float("nan")), ("cpx_weight", "gamma"),
                                       ("coulomb_smoothing", 0.0)])
def test_bad_reading_keys_are_rejected(key, value):
    with pytest.raises(C.ConfigError) as e:
        C.from_dict(DipCpxLdfConfig, {key: value})
    assert key in str(e.value)
