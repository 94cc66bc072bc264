"""jd.FunctionPlant: a cart-pole written as a plain function runs in jd.Loop and jd.monte_carlo, equals a hand-written
RK4 loop (continuous) and a hand-written map (discrete), and jax.grad through a parameter of the function agrees
with central finite differences; the docs/engine.md example runs."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from test_readme_example import ENGINE, python_block, run_block

DT, SUBSTEPS, STEPS = 0.01, 10, 150
NAMES = ("x", "phi", "x_dot", "phi_dot")
P = dict(mc=1.0, mp=0.1, l=0.5, g=9.81)


def cartpole(s, u, p):
    """A point mass mp on a rod l over a cart mc pushed by u; phi = 0 upright."""
    sn, cs = jnp.sin(s[1]), jnp.cos(s[1])
    xdd = (u[0] + p["mp"] * sn * (p["l"] * s[3] ** 2 - p["g"] * cs)) / (p["mc"] + p["mp"] * sn**2)
    return jnp.stack([s[2], s[3], xdd, (p["g"] * sn - xdd * cs) / p["l"]])


def rk4_period(s, u, p):
    """One sample period by SUBSTEPS classical RK4 steps with u held: the hand-written reference."""
    h = DT / SUBSTEPS
    for _ in range(SUBSTEPS):
        k1 = cartpole(s, u, p)
        k2 = cartpole(s + h / 2 * k1, u, p)
        k3 = cartpole(s + h / 2 * k2, u, p)
        k4 = cartpole(s + h * k3, u, p)
        s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return s


class Exact(jd.Sensor):
    """y = x: the comparison needs no measurement noise."""

    def step(self, state, x, key, k):
        return state, x, None


@pytest.fixture(scope="module")
def gain():
    plant = jd.FunctionPlant(cartpole, state_names=NAMES, input_names="F", params=P)
    A, B = jd.linearize(plant)
    K, _, _ = jd.control.lqr(A, B, jnp.diag(jnp.array([1.0, 10, 0, 0])), 0.1)
    return K


def rollout(plant, K):
    loop = jd.Loop(plant, sensor=Exact(), estimator=jd.Passthrough(), controller=jd.control.StateFeedback(K), dt=DT,
                   substeps=SUBSTEPS)
    return jd.Rollout(loop, x0=jd.Ball(jnp.zeros(4), 0.2), steps=STEPS, save=save_x,
                      metrics=jd.metrics.Moments("x"))


def save_x(s):
    return s.x


@jax.jit
def hand_loop(x0, K):
    def period(x, _):
        return rk4_period(x, -K @ x, P), x
    return jax.lax.scan(period, x0, None, length=STEPS)[1]


def test_plant_protocol_and_names():
    plant = jd.FunctionPlant(cartpole, state_names=NAMES, input_names="F", params=P)
    assert (plant.n, plant.m, plant.index("phi"), plant.continuous) == (4, 1, 1, True)
    x, u = jnp.array([0.1, 0.2, -0.3, 0.4]), jnp.array([0.5])
    np.testing.assert_array_equal(plant.vector_field(x, u), cartpole(x, u, P))
    assert all(v.dtype == jnp.float64 and not v.weak_type for v in jax.tree_util.tree_leaves(plant.params))
    with pytest.raises(TypeError, match="vector field"):
        plant.step(x, u)
    with pytest.raises(ValueError, match="state_names"):
        jd.FunctionPlant(cartpole, state_names=("x", "x"), params=P)
    plain = jd.FunctionPlant(lambda x, u: -x + u, state_names=("a",))  # no params: f(x, u)
    np.testing.assert_array_equal(plain.vector_field(jnp.array([2.0]), jnp.array([0.5])), [-1.5])


def test_continuous_function_plant_in_loop_and_monte_carlo_equals_hand_rk4(gain):
    plant = jd.FunctionPlant(cartpole, state_names=NAMES, input_names="F", params=P)
    sol = jd.monte_carlo(rollout(plant, gain), 0, 8)
    assert np.all(np.asarray(sol.result) == jd.RESULTS.ok)
    xs = np.asarray(sol.saved)  # (seeds, periods, 4): x_k at the start of each period
    assert xs.shape == (8, STEPS, 4) and np.abs(xs[:, 0]).max() > 0.05  # the seeds start apart
    for seed in range(8):
        ref = np.asarray(hand_loop(jnp.asarray(xs[seed, 0]), gain))
        np.testing.assert_allclose(xs[seed], ref, rtol=1e-12, atol=1e-13)
    assert np.abs(xs[:, -1, 1]).max() < 0.2 * np.abs(xs[:, 0, 1]).max()  # LQR brings the rod back toward upright


def test_discrete_function_plant_equals_the_map(gain):
    # the RK4 period itself, as a discrete map: the loop must apply it once per period, whatever substeps says
    plant = jd.FunctionPlant(rk4_period, state_names=NAMES, input_names="F", params=P, discrete=True)
    assert not plant.continuous
    with pytest.raises(TypeError, match="step"):
        plant.vector_field(jnp.zeros(4), jnp.zeros(1))
    sol = jd.monte_carlo(rollout(plant, gain), 0, 4)
    xs = np.asarray(sol.saved)
    for seed in range(4):
        np.testing.assert_allclose(xs[seed], np.asarray(hand_loop(jnp.asarray(xs[seed, 0]), gain)), rtol=1e-12,
                                   atol=1e-13)
    # linearize takes the map's Jacobians: the continuous plant's exact discretisation to O(h^4)
    Ad, _ = jd.linearize(plant)
    Ac, Bc = jd.linearize(jd.FunctionPlant(cartpole, state_names=NAMES, input_names="F", params=P))
    np.testing.assert_allclose(Ad, jd.zoh(Ac, Bc, DT).Phi, rtol=0, atol=1e-9)


def test_grad_through_a_parameter_matches_finite_differences(gain):
    run = rollout(jd.FunctionPlant(cartpole, state_names=NAMES, input_names="F", params=P), gain)

    def cost(length):  # mean phi^2 over 16 seeds as a function of the rod length the plant has
        r = eqx.tree_at(lambda t: t.loop.plant.params["l"], run, length)
        return jd.monte_carlo(r, 0, 16).metrics["mean_sq"][:, 1].mean()

    value, grad = jax.value_and_grad(cost)(0.5)
    h = 1e-5
    fd = (cost(0.5 + h) - cost(0.5 - h)) / (2 * h)
    assert value > 0 and abs(float(grad)) > 1e-6
    np.testing.assert_allclose(float(grad), float(fd), rtol=1e-6)


def test_engine_md_function_plant_example_runs(capsys):
    code = python_block(ENGINE.read_text(), "\n## A plain function as a plant\n")
    ns = run_block(code, ENGINE)
    printed = capsys.readouterr().out
    value, grad = (float(v) for v in re.search(r"mean phi\^2 (\S+), d/dl (\S+)", printed).groups())
    assert np.all(np.asarray(ns["sol"].result) == jd.RESULTS.ok)
    assert value > 0 and np.isfinite(grad) and grad != 0
