"""step_response / initial_response (run by jaxdip.engine.simulate) against python-control 0.10 on 60 random
systems (generic, marginal, badly scaled; continuous and discrete), and a gradient through the loop."""

import jaxdip  # noqa: F401  (enables float64)

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.control import StateSpace, initial_response, ss, step_response
from jaxdip.engine.checks import ArgumentError
from control_systems import batch, fd_grad, rel, stack

COUNT = 60
TOL = 1e-9


@pytest.mark.parametrize("discrete", [False, True])
def test_step_and_initial_responses_match_python_control(discrete):
    systems = batch(COUNT, discrete=discrete, seed=1800)
    dt = 0.1 if discrete else 0.0
    T = np.arange(40) * 0.1
    A, B, C, D = stack(systems)
    X0 = np.random.default_rng(1).standard_normal((COUNT, 4))
    step = jax.jit(jax.vmap(lambda A, B, C, D: step_response(StateSpace(A, B, C, D, dt), T)[1]))(A, B, C, D)
    free = jax.jit(jax.vmap(lambda A, B, C, D, x0: initial_response(StateSpace(A, B, C, D, dt), T, x0)[1]))(
        A, B, C, D, X0)
    for i, (kind, *_) in enumerate(systems):
        sys = control.ss(A[i], B[i], C[i], D[i], dt)
        ys = control.step_response(sys, T).outputs
        yi = control.initial_response(sys, T, X0[i]).outputs
        assert step[i].shape == ys.shape and free[i].shape == yi.shape
        assert rel(step[i], ys) < TOL, (i, kind, rel(step[i], ys))
        assert rel(free[i], yi) < TOL, (i, kind, rel(free[i], yi))


def test_siso_is_squeezed_and_gradient_matches_finite_differences():
    kind, A, B, C, D = batch(1, m=1, p=1, stable=True, seed=1900)[0]
    T = np.linspace(0, 3, 31)
    t, y = step_response(ss(A, B, C, D), T)
    assert y.shape == (31,) and np.array_equal(t, T)

    @jax.jit
    def f(A):
        return jnp.sum(step_response(StateSpace(A, B, C, D), T)[1] ** 2)

    assert rel(jax.grad(f)(A), fd_grad(lambda x: float(f(x)), A)) < 1e-6


def test_bad_times_raise():
    sys = ss(-np.eye(2), np.ones((2, 1)), np.ones((1, 2)))
    with pytest.raises(ArgumentError, match="evenly spaced"):
        step_response(sys, [0.0, 0.1, 0.3])
    with pytest.raises(ArgumentError, match="starting at 0"):
        initial_response(sys, [1.0, 2.0], [1.0, 0.0])
    with pytest.raises(ArgumentError, match="dt=0.1"):
        step_response(ss(0.5 * np.eye(2), np.ones((2, 1)), np.ones((1, 2)), dt=0.1), [0.0, 0.2])
