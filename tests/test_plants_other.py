"""Tests of the TWIP, reaction-wheel pendulum, Lorenz and §2.7 example plants.

Each test checks a plant against something independent of its implementation: a closed form printed in the
documents, a plain-NumPy solve written from the printed equations, energy conservation, a reference ODE solver
at tight tolerance, or the documents' published gains.
"""

import jaxdip  # noqa: F401  (enables float64 first)

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from jaxdip.plants import examples2d, lorenz, rwp, twip
from jaxdip.engine.integrate import rk4_zoh
from jaxdip.engine.roles import linearize

# ---- TWIP ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("table", ["8.1", "8.2"])
def test_twip_autodiff_linearisation_matches_eq79(table):
    p = twip.TWIP.table(table)
    A_ad, B_ad = linearize(p, jnp.zeros(4), jnp.zeros(1))
    A_cf, B_cf = twip.linear_model_closed_form(p)
    A_ad, B_ad, A_cf, B_cf = map(np.asarray, (A_ad, B_ad, A_cf, B_cf))

    np.set_printoptions(precision=6, linewidth=140)
    print(f"\nTWIP Table {table}: eq. (79) closed form A =\n{A_cf}\nB^T = {B_cf.T}")
    print(f"|A_autodiff - A_(79)| per entry =\n{np.abs(A_ad - A_cf)}")
    print(f"|B_autodiff - B_(79)|^T per entry = {np.abs(B_ad - B_cf).T}")
    rel_A = np.abs(A_ad - A_cf) / np.maximum(np.abs(A_cf), 1e-300)
    rel_B = np.abs(B_ad - B_cf) / np.maximum(np.abs(B_cf), 1e-300)
    print(f"max relative difference (non-zero entries): A {rel_A[A_cf != 0].max():.3e}, B {rel_B[B_cf != 0].max():.3e}")

    # The structural zeros of (79) must be zeros of the linearisation, and every entry must agree to 1e-10.
    np.testing.assert_array_equal(A_ad[A_cf == 0], 0.0)
    np.testing.assert_array_equal(B_ad[B_cf == 0], 0.0)
    np.testing.assert_allclose(A_ad, A_cf, rtol=1e-10, atol=0)
    np.testing.assert_allclose(B_ad, B_cf, rtol=1e-10, atol=0)
    # Upright is unstable (a positive real eigenvalue), as it must be for an inverted pendulum.
    assert np.linalg.eigvals(A_cf).real.max() > 1.0


def _twip_numpy(p, x, V):
    """(72)-(73) in theta = pi + phi, solved with np.linalg.solve: an independent transcription."""
    xd, phi, phid = x[1], x[2], x[3]
    th, thd = np.pi + phi, phid
    s, c = np.sin(th), np.cos(th)
    beta = 2 * p.Mw + 2 * p.Iw / p.r**2 + p.Mp
    # Unknowns [x'', theta''].
    M = np.array(
        [
            [p.Mp * p.l * c, p.Ip + p.Mp * p.l**2],  # (72), -Mp l x'' cos(th) moved to the left
            [beta, p.Mp * p.l * c],  # (73)
        ]
    )
    rhs = np.array(
        [
            2 * p.km * p.ke / (p.R * p.r) * xd - 2 * p.km / p.R * V - p.Mp * p.g * p.l * s,
            2 * p.km / (p.R * p.r) * V - 2 * p.km * p.ke / (p.R * p.r**2) * xd + p.Mp * p.l * thd**2 * s,
        ]
    )
    xdd, thdd = np.linalg.solve(M, rhs)
    return np.array([xd, xdd, phid, thdd])


@pytest.mark.parametrize("table", ["8.1", "8.2"])
def test_twip_nonlinear_matches_numpy_solve(table):
    params = twip.TWIP.table(table)
    rng = np.random.default_rng(0)
    f = jax.jit(twip.f)
    for _ in range(20):
        x = rng.uniform([-2, -3, -np.pi, -5], [2, 3, np.pi, 5])
        V = rng.uniform(-12, 12)
        ours = np.asarray(f(params, jnp.asarray(x), jnp.array([V])))
        ref = _twip_numpy(params, x, V)
        np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_twip_upright_is_an_exact_equilibrium():
    p = twip.TWIP()
    assert np.all(np.asarray(twip.f(p, jnp.zeros(4), jnp.zeros(1))) == 0.0)


# ---- Reaction-wheel pendulum --------------------------------------------------------------------------------


def test_rwp_table2_gains_stabilise_with_settled_B_not_with_printed_B():
    p = rwp.RWP()
    A, B = (np.asarray(m) for m in rwp.reduced_linear_model(p))
    K = np.array(rwp.K_TABLE2).reshape(1, 3)
    eig = np.linalg.eigvals(A - B @ K)
    print(f"\nRWP eig(A - BK), B from (2)-(3): {eig}")
    assert np.all(eig.real < 0)

    # B as printed in (4): [0, +k/J, k/J + k/Jr]. With it the published gains do NOT stabilise the model,
    # which is why docs/models.md takes the input column from (2)-(3) (-k/J), consistent with the observer (9).
    J = p.Jp + p.mp * p.lp**2 + p.mr * p.lr**2
    B_printed = np.array([[0.0], [p.k / J], [p.k / J + p.k / p.Jr]])
    eig_printed = np.linalg.eigvals(A - B_printed @ K)
    print(f"RWP eig(A - BK), B as printed in (4): {eig_printed}")
    assert np.any(eig_printed.real > 0)


def test_rwp_reduced_model_matches_autodiff_of_full_plant():
    p = rwp.RWP()
    A_full, B_full = linearize(p, jnp.zeros(4), jnp.zeros(1))
    keep = [0, 1, 3]  # theta, theta_dot, theta_r_dot
    A_red, B_red = rwp.reduced_linear_model(p)
    np.testing.assert_allclose(np.asarray(A_full)[np.ix_(keep, keep)], A_red, rtol=1e-14, atol=0)
    np.testing.assert_allclose(np.asarray(B_full)[keep], B_red, rtol=1e-14, atol=0)
    # theta_r does not enter the dynamics: its column of the full A is zero.
    np.testing.assert_array_equal(np.asarray(A_full)[:, 2], 0.0)


def test_rwp_reduced_model_uses_table1_numbers():
    # Independent arithmetic from Table 1: J = 3.8e-3 + 0.58*0.1^2 + 0.35*0.22^2, ml = 0.058 + 0.077.
    J = 3.8e-3 + 0.58 * 0.01 + 0.35 * 0.0484
    ml = 0.058 + 0.077
    A, B = rwp.reduced_linear_model(rwp.RWP())
    np.testing.assert_allclose(A[1, 0], ml * 9.81 / J, rtol=1e-12)
    np.testing.assert_allclose(A[2, 0], -ml * 9.81 / J, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(B).ravel(), [0.0, -3.69e-2 / J, 3.69e-2 / J + 3.69e-2 / 12.48e-4], rtol=1e-12)


def test_rwp_energy_conserved_without_input():
    p = rwp.RWP()
    x0 = jnp.array([0.5, 0.0, 0.0, 5.0])  # falls from 0.5 rad, swings through the bottom; wheel spinning
    u = jnp.zeros(1)
    n = int(round(5.0 / rwp.DT))

    @jax.jit
    def run(x0):
        def body(x, _):
            x = rk4_zoh(rwp.f, p, x, u, rwp.DT, substeps=10)
            return x, (x, rwp.energy(p, x))

        return jax.lax.scan(body, x0, None, length=n)[1]

    xs, E = run(x0)
    E0 = rwp.energy(p, x0)
    drift = float(jnp.max(jnp.abs(E - E0)) / jnp.abs(E0))
    print(f"\nRWP relative energy drift over 5 s: {drift:.3e}; max |theta_dot| {float(jnp.abs(xs[:, 1]).max()):.2f}")
    assert drift < 1e-9
    # The motion is not trivial: the pendulum swung through the bottom, trading potential for kinetic energy.
    assert float(jnp.abs(xs[:, 0]).max()) > 3.0 and float(jnp.abs(xs[:, 1]).max()) > 10.0

    # With a constant current, energy is not conserved (the test would notice a wrong input column).
    def step_I(x, _):
        return rk4_zoh(rwp.f, p, x, jnp.array([0.5]), rwp.DT, substeps=10), None

    xI, _ = jax.lax.scan(step_I, x0, None, length=100)
    assert abs(float(rwp.energy(p, xI) - E0)) > 1e-3


# ---- Lorenz ---------------------------------------------------------------------------------------------------


def test_lorenz_rk4_matches_dop853():
    p = lorenz.Lorenz()
    x0 = np.array([1.0, 1.0, 1.0])
    dt, n = 0.001, 1000

    @jax.jit
    def run(x0):
        def body(x, _):
            x = rk4_zoh(lorenz.f, p, x, jnp.zeros(1), dt, substeps=4)
            return x, x

        return jax.lax.scan(body, x0, None, length=n)[1]

    ours = np.asarray(run(jnp.asarray(x0)))

    def rhs(t, x):
        return [p.sigma * (x[1] - x[0]), x[0] * (p.rho - x[2]) - x[1], x[0] * x[1] - p.beta * x[2]]

    t_eval = dt * np.arange(1, n + 1)
    ref = solve_ivp(rhs, (0.0, t_eval[-1]), x0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t_eval).y.T
    err = np.abs(ours - ref).max()
    print(f"\nLorenz RK4 (dt=1e-3, 4 substeps) vs DOP853 over 1 time unit: max error {err:.3e}")
    assert err < 1e-6
    assert np.abs(ref).max() > 5.0  # the trajectory really moved


def test_lorenz_fixed_points():
    p = lorenz.Lorenz()
    c = np.sqrt(8.0 / 3.0 * 27.0)
    expected = np.array([[0.0, 0.0, 0.0], [c, c, 27.0], [-c, -c, 27.0]])
    np.testing.assert_allclose(lorenz.equilibria(p), expected, rtol=1e-15, atol=0)
    for xe in expected:
        np.testing.assert_allclose(lorenz.f(p, jnp.asarray(xe), jnp.zeros(1)), 0.0, atol=1e-12)
    # A point off the fixed points is not one.
    assert np.abs(np.asarray(lorenz.f(p, jnp.asarray(expected[1] + 0.1), jnp.zeros(1)))).max() > 0.1


def test_lorenz_output_matrix_measures_y_and_z():
    x = np.array([1.5, -2.5, 30.0])
    np.testing.assert_array_equal(np.asarray(lorenz.output_matrix()) @ x, [-2.5, 30.0])


# ---- §2.7 two-dimensional examples ----------------------------------------------------------------------------


def test_example2d_linear_step_matches_numpy():
    plant = examples2d.Linear()
    A = np.array([[0.9974, 0.0539], [-0.1078, 1.1591]])
    B = np.array([0.0013, 0.0539])
    rng = np.random.default_rng(1)
    for _ in range(10):
        x, u = rng.normal(size=2), rng.normal()
        np.testing.assert_allclose(plant.step(jnp.asarray(x), jnp.array([u])), A @ x + B * u, rtol=1e-14, atol=1e-15)


def test_example2d_nonlinear_step_matches_numpy():
    plant = examples2d.Nonlinear()
    rng = np.random.default_rng(2)
    for _ in range(10):
        x, u = rng.normal(scale=2.0, size=2), rng.normal()
        fx = np.array([2.2 * np.sin(0.5 * x[0]) + 0.1 * x[1], 0.1 * x[0] ** 2 + 1.8 * x[1]])
        gx = np.array([0.0, 2.0 + 0.1 * np.cos(x[1])])
        np.testing.assert_allclose(plant.step(jnp.asarray(x), jnp.array([u])), fx + gx * u, rtol=1e-14, atol=1e-15)


def test_example2d_linear_unstable_and_controllable():
    p = examples2d.Linear()
    A, B = np.asarray(p.A), np.asarray(p.B)
    rho = np.abs(np.linalg.eigvals(A)).max()
    print(f"\n§2.7.1 open-loop spectral radius {rho:.6f}")
    assert rho > 1.0
    ctrb = np.hstack([B, A @ B])
    assert np.linalg.matrix_rank(ctrb) == 2
    assert abs(np.linalg.det(ctrb)) > 1e-4  # not merely numerically rank 2


def test_example2d_plants_are_discrete_and_jittable():
    for plant in (examples2d.Linear(), examples2d.Nonlinear()):
        assert not plant.continuous and plant.n == 2 and plant.m == 1
        with pytest.raises(TypeError):
            plant.vector_field(jnp.zeros(2), jnp.zeros(1))
        step = jax.jit(lambda x, u: plant.step(x, u))
        x1 = step(jnp.array([2.0, 1.0]), jnp.zeros(1))
        assert x1.shape == (2,) and x1.dtype == jnp.float64


@pytest.mark.parametrize("table", ["8.1", "8.2"])
def test_twip_plant_vmapped_matches_numpy(table):
    """``twip.TWIP``'s vector field (vmapped) against the NumPy solve of (72)-(73); the unmodeled variant with zero
    gains equals it bit for bit."""
    p = twip.TWIP.table(table)
    key = jax.random.PRNGKey(1)
    xs = jax.random.normal(key, (64, 4))
    us = 5.0 * jax.random.normal(jax.random.fold_in(key, 1), (64, 1))
    got = np.asarray(jax.vmap(p.vector_field)(xs, us))
    for x, u, g in zip(np.asarray(xs), np.asarray(us), got):
        ref = _twip_numpy(p, x, u[0])
        np.testing.assert_allclose(g, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_array_equal(np.asarray(jax.vmap(twip.TWIPUnmodeled.table(table).vector_field)(xs, us)), got)
    assert twip.TWIP.table(table).state_names == twip.STATE_NAMES
