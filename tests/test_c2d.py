"""c2d (ZOH, FOH, Tustin with and without prewarping) against python-control's sample_system / SciPy's
cont2discrete on 60 random systems (generic, marginal, badly scaled), the converters, and the gradient in the
sample period against finite differences."""

import jaxdip  # noqa: F401  (enables float64)

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.control import StateSpace, c2d, from_control, ss, to_control
from jaxdip.engine.checks import ArgumentError
from jaxdip.sim.discretize import sample, zoh
from control_systems import batch, fd_grad, rel, stack

COUNT = 60
TOL = 1e-9


@pytest.mark.parametrize("method", ["zoh", "foh", "tustin"])
def test_c2d_matches_python_control(method):
    systems = batch(COUNT, seed=1300)
    A, B, C, D = stack(systems)
    h = 0.05
    out = jax.jit(jax.vmap(lambda A, B, C, D: sample(A, B, C, D, h, method)))(A, B, C, D)
    for i, (kind, *_) in enumerate(systems):
        ref = control.sample_system(control.ss(A[i], B[i], C[i], D[i]), h, method)
        for got, want in zip(out, (ref.A, ref.B, ref.C, ref.D)):
            assert rel(got[i], want) < TOL, (method, i, kind, rel(got[i], want))


def test_c2d_on_state_space_with_prewarping_matches_python_control():
    for kind, A, B, C, D in batch(6, seed=1400):
        sys = control.ss(A, B, C, D)
        for method, w in (("zoh", None), ("tustin", None), ("tustin", 3.0)):
            ref = control.sample_system(sys, 0.1, method, prewarp_frequency=w)
            got = c2d(from_control(sys), 0.1, method, prewarp_frequency=w)
            assert got.dt == 0.1
            for g, r in zip((got.A, got.B, got.C, got.D), (ref.A, ref.B, ref.C, ref.D)):
                assert rel(g, r) < TOL, (method, kind)


def test_zoh_is_the_plants_discretisation():
    kind, A, B, C, D = batch(1, seed=1500)[0]
    d = zoh(A, B, 0.01)
    Ad, Bd, _, _ = sample(A, B, C, D, 0.01, "zoh")
    assert np.array_equal(np.asarray(Ad), np.asarray(d.Phi)) and np.array_equal(np.asarray(Bd), np.asarray(d.W))


@pytest.mark.parametrize("method", ["zoh", "foh", "tustin"])
def test_gradient_in_the_period_matches_finite_differences(method):
    kind, A, B, C, D = batch(1, seed=1600)[0]

    @jax.jit
    def f(h):
        return jnp.stack([jnp.sum(M) for M in sample(A, B, C, D, h, method)])

    g = jax.jacobian(f)(0.1)
    assert rel(g, fd_grad(lambda x: np.asarray(f(float(x))), np.array(0.1))) < 1e-6


def test_converters_round_trip():
    kind, A, B, C, D = batch(1, seed=1700)[0]
    for dt in (0.0, 0.2):
        sys = ss(A, B, C, D, dt)
        pc = to_control(sys)
        assert isinstance(pc, control.StateSpace) and pc.dt == dt
        back = from_control(pc)
        assert back.dt == dt and all(np.array_equal(np.asarray(x), y) for x, y in
                                     zip((back.A, back.B, back.C, back.D), (A, B, C, D)))
    tf = from_control(control.tf([1.0, 2.0], [1.0, 3.0, 2.0]))  # a transfer function goes through control.ss
    assert tf.A.shape == (2, 2) and tf.dt == 0.0


def test_bad_arguments_raise():
    sys = ss(-np.eye(2), np.ones((2, 1)), np.ones((1, 2)))
    with pytest.raises(ArgumentError, match="method"):
        c2d(sys, 0.1, "euler")
    with pytest.raises(ArgumentError, match="h must be positive"):
        c2d(sys, -0.1)
    with pytest.raises(ArgumentError, match="continuous-time"):
        c2d(ss(np.eye(2), np.ones((2, 1)), np.ones((1, 2)), dt=0.1), 0.1)
    with pytest.raises(ArgumentError, match="Tustin"):
        c2d(sys, 0.1, "zoh", prewarp_frequency=1.0)
    with pytest.raises(ArgumentError, match="singular"):
        sample(np.array([[20.0]]), np.ones((1, 1)), np.ones((1, 1)), np.zeros((1, 1)), 0.1, "tustin")
    with pytest.raises(ArgumentError, match=r"B must be \(2, None\)|B must be"):
        ss(-np.eye(2), np.ones((3, 1)), np.ones((1, 2)))
    assert isinstance(sys, StateSpace)
