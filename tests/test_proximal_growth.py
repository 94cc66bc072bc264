"""Checks of Thm 1.3.2 / Prop. 1.4.1 / Prop. 2.4.2 (jaxdip.theory.proximal_growth) against independent routes:
scipy's least_squares for the proximal step of (1.9), the published-P module's closed loop, and a finite
difference of 1/2 ||x||_P^2 along the exact flow."""

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla
from scipy.optimize import least_squares

from jaxdip.plants import lorenz
from jaxdip.theory import proximal_growth as pg
from jaxdip.theory.published_p import linear_rp_eigs


def test_gauss_newton_prox_of_19_matches_scipy():
    f = pg.lorenz_map(0.01)
    C = np.asarray(lorenz.output_matrix())
    x = jnp.array([3.0, -2.0, 24.0])
    y0, y1 = C @ np.asarray(x) + 0.03, C @ np.asarray(f(x)) - 0.02
    xhat, w = np.array([3.5, -1.0, 23.0]), 0.3

    def res(z):
        return jnp.concatenate([jnp.asarray(C) @ z - y0, jnp.asarray(C) @ f(z) - y1, jnp.sqrt(w / 2) * (z - xhat)])

    got = np.asarray(pg._gauss_newton(res, jnp.asarray(xhat), 30))
    want = least_squares(lambda z: np.asarray(res(jnp.asarray(z))), xhat, xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-9)


def test_rp_closed_loop_and_decay_rate_are_independent_routes():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    B = rng.normal(size=(4, 1))
    M = rng.normal(size=(4, 4))
    P = M @ M.T + 4 * np.eye(4)
    g = 7.0
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(pg.rp_closed_loop(A, B, P, g))),
                               np.sort_complex(linear_rp_eigs(A, B, P, g)), rtol=1e-9, atol=1e-9)
    rate = pg.decay_rate(A, B, P, g)
    # the maximiser: the generalised eigenvector; d/dt 1/2 x^T P x at t = 0 by a central difference of the flow
    Acl = pg.rp_closed_loop(A, B, P, g)
    w, V = sla.eigh(0.5 * (P @ Acl + Acl.T @ P), P)
    x = V[:, -1]
    h = 1e-6
    V_of = lambda t: 0.5 * (sla.expm(Acl * t) @ x) @ P @ (sla.expm(Acl * t) @ x)
    np.testing.assert_allclose((V_of(h) - V_of(-h)) / (2 * h) / (x @ P @ x), rate, rtol=1e-6)
    # and no random direction decays more slowly than the rate says
    for _ in range(200):
        z = rng.normal(size=4)
        assert (z @ P @ Acl @ z) / (z @ P @ z) <= rate + 1e-12


def test_growing_weights_reach_the_least_squares_point_on_a_small_linear_system():
    Phi = np.array([[1.0, 0.01], [-0.02, 0.99]])
    C = np.array([[1.0, 0.0]])
    r = pg.linear_least_squares(jax.random.PRNGKey(1), Phi, C, window=2, trials=4, steps=120, gamma0=1.0)
    assert np.all(r.err_growing < 1e-8)
    assert np.all(r.err_constant > 1e-6)
    assert np.all(r.growth > 1.0)
