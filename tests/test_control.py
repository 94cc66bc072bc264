"""Controllers against independent references: finite differences, python-control, simulation, closed forms."""

import control as ct
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.control import care, dare, dlqr, lqr
from jaxdip.control.power_series import PowerSeries, third_order_term
from jaxdip.control.projection import projected_closed_loop
from jaxdip.control.spd import P_v, P_Vs, gram_schmidt_basis, householder_basis, surface_normal
from jaxdip.plants import dip, examples2d
from jaxdip.engine.roles import linearize
from jaxdip.sim import zoh

Q_DIP = np.diag([30.0, 350.0, 100.0, 0, 0, 0])


def _dip_linear():
    return [np.asarray(m) for m in linearize(dip.DIP(), jnp.zeros(6), jnp.zeros(1))]


def _fd(f, x, eps):
    return (f(x + eps) - f(x - eps)) / (2 * eps)


@pytest.mark.parametrize("discrete", [False, True])
def test_lqr_gain_matches_python_control_on_dip(discrete):
    A, B = _dip_linear()
    if discrete:
        d = zoh(A, B, 1e-3)
        A, B = np.asarray(d.Phi), np.asarray(d.W)
        K, S, _ = dlqr(A, B, Q_DIP, 0.1)
        Kc, Sc, _ = ct.dlqr(A, B, Q_DIP, 0.1)
    else:
        K, S, _ = lqr(A, B, Q_DIP, 0.1)
        Kc, Sc, _ = ct.lqr(A, B, Q_DIP, 0.1)
    assert np.max(np.abs(K - Kc)) / np.max(np.abs(Kc)) < 1e-9
    assert np.max(np.abs(S - Sc)) / np.max(np.abs(Sc)) < 1e-9


@pytest.mark.parametrize("which", ["care", "dare"])
def test_riccati_gradients_match_finite_differences(which):
    rng = np.random.default_rng(3)
    A0 = rng.normal(size=(4, 4)) * (0.4 if which == "dare" else 1.0)
    B0 = rng.normal(size=(4, 2))
    Q0 = np.diag(rng.uniform(0.5, 2.0, 4))
    R0 = np.diag(rng.uniform(0.5, 2.0, 2))
    solve = care if which == "care" else dare
    dirs = [rng.normal(size=s) for s in (A0.shape, B0.shape, Q0.shape, R0.shape)]
    dirs[2] = dirs[2] + dirs[2].T
    dirs[3] = dirs[3] + dirs[3].T
    W = rng.normal(size=(4, 4))

    def scalar(t):  # a generic linear functional of X along a joint direction in (A, B, Q, R)
        X = solve(A0 + t * dirs[0], B0 + t * dirs[1], Q0 + t * dirs[2], R0 + t * dirs[3])
        return jnp.sum(W * X)

    scalar_j = jax.jit(scalar)
    g = jax.jit(jax.grad(scalar))(0.0)
    fwd = jax.jit(jax.jacfwd(scalar))(0.0)
    fd = _fd(lambda t: float(scalar_j(t)), 0.0, 1e-5)
    assert abs(g - fd) <= 1e-6 * max(1.0, abs(fd))
    assert abs(fwd - g) <= 1e-10 * max(1.0, abs(g))


def test_lqr_gain_gradient_wrt_weights_on_dip():
    A, B = _dip_linear()

    @jax.jit
    def k_alpha(logq):
        Q = jnp.diag(jnp.exp(logq))
        return lqr(A, B, Q, 0.1)[0][0, 1]

    logq = jnp.log(jnp.array([30.0, 350.0, 100.0, 1e-3, 1e-3, 1e-3]))
    g = np.asarray(jax.jit(jax.grad(k_alpha))(logq))
    for i in range(3):
        e = np.zeros(6)
        e[i] = 1e-5
        fd = (float(k_alpha(logq + e)) - float(k_alpha(logq - e))) / 2e-5
        assert abs(g[i] - fd) <= 1e-5 * max(1.0, abs(fd)), (i, g[i], fd)


def test_third_order_term_matches_finite_differences():
    plant = dip.DIP()
    drift = lambda z: plant.vector_field(z, jnp.zeros(1))
    A = np.asarray(jax.jacfwd(drift)(jnp.zeros(6)))
    x = jnp.array([0.2, 0.5, -0.3, 1.0, 2.0, -1.0])
    f3 = np.asarray(third_order_term(drift, x))
    # f is odd, so f(t x) - t A x = t^3 f3 + O(t^5): the remainder / t^3 converges to f3 quadratically in t
    errs = []
    for t in (0.08, 0.04, 0.02):
        r = (np.asarray(drift(t * x)) - t * A @ np.asarray(x)) / t**3
        errs.append(np.max(np.abs(r - f3)))
    assert errs[-1] < 1e-3 * np.max(np.abs(f3))
    assert 3.0 < errs[0] / errs[1] < 5.0 and 3.0 < errs[1] / errs[2] < 5.0
    # a cubic: f3 is homogeneous of degree 3
    np.testing.assert_allclose(third_order_term(drift, 2 * x), 8 * f3, rtol=1e-12, atol=1e-12)


def test_power_series_linear_part_is_lqr():
    ps = PowerSeries.design(dip.DIP(), Q_DIP, 0.1)
    law = lambda x: ps.step((), x, None, 0)[1]
    J = np.asarray(jax.jit(jax.jacfwd(law))(jnp.zeros(6)))
    A, B = _dip_linear()
    Kc, _, _ = ct.lqr(A, B, Q_DIP, 0.1)
    np.testing.assert_allclose(J, -Kc, rtol=1e-9, atol=1e-9)
    x = jnp.array([0.0, 0.1, -0.05, 0, 0, 0])
    assert abs(float(jax.jit(law)(x)[0]) + float(Kc[0] @ x)) > 1e-4  # the cubic part is not nil


def test_spd_constructions():
    rng = np.random.default_rng(0)
    for _ in range(5):
        v = rng.normal(size=6)
        U = np.asarray(householder_basis(v))
        np.testing.assert_allclose(U.T @ U, np.eye(6), atol=1e-12)
        np.testing.assert_allclose(U[:, 0], v / np.linalg.norm(v), atol=1e-12)
        P = np.asarray(P_v(v, 1e6))
        np.testing.assert_allclose(P @ (v / np.linalg.norm(v)), 1e6 * v / np.linalg.norm(v), rtol=1e-10)
        ev = np.linalg.eigvalsh(P)
        np.testing.assert_allclose(np.sort(ev), [1, 1, 1, 1, 1, 1e6], rtol=1e-9)
        V = np.linalg.qr(rng.normal(size=(6, 2)))[0]
        U2 = np.asarray(gram_schmidt_basis(V))
        np.testing.assert_allclose(U2.T @ U2, np.eye(6), atol=1e-12)
        np.testing.assert_allclose(U2[:, :2], V, atol=1e-12)
        P2 = np.asarray(P_Vs(V, [1e6, 1e5]))
        np.testing.assert_allclose(P2 @ V, V * [1e6, 1e5], rtol=1e-9)
    # v = -e1 is the degenerate case of the Householder pair
    U = np.asarray(householder_basis(-np.eye(3)[0]))
    np.testing.assert_allclose(U[:, 0], -np.eye(3)[0], atol=1e-15)


def test_linear_example_thesis_v_is_stabilising():
    prm = examples2d.Linear()
    A, B = jnp.asarray(prm.A), jnp.asarray(prm.B).reshape(2, 1)
    T = projected_closed_loop(A, B, P_v(jnp.array([-0.9975, -0.07]), 1e6))
    assert np.max(np.abs(np.linalg.eigvals(np.asarray(T)))) < 1
    T_bad = projected_closed_loop(A, B, P_v(jnp.array([0.07, -0.9975]), 1e6))
    assert np.max(np.abs(np.linalg.eigvals(np.asarray(T_bad)))) > 1


def test_surface_normal_places_the_on_surface_poles():
    A, B = _dip_linear()
    poles = np.array([-1.0 + 1j, -1.0 - 1j, -3.0, -5.0, -8.0])
    c = np.asarray(surface_normal(A, B, poles))
    assert c @ B[:, 0] > 0
    P = np.asarray(P_v(c, 1e9))
    gamma = 40.0
    K = np.linalg.solve(B.T @ P @ B, gamma * B.T @ P + B.T @ P @ A)
    ev = np.sort_complex(np.linalg.eigvals(A - B @ K))
    want = np.sort_complex(np.concatenate([poles, [-gamma]]))
    np.testing.assert_allclose(ev, want, atol=1e-3)
