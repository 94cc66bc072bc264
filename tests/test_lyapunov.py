"""lyap/dlyap (Lyapunov and Sylvester), ctrb/obsv and gram against python-control 0.10 / SciPy on 60 random
systems each, the failures, and gradients of gram against finite differences."""

import jaxdip  # noqa: F401  (enables float64)

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla

from jaxdip.control import LyapunovError, ctrb, dlyap, gram, lyap, obsv, ss
from jaxdip.engine.checks import ArgumentError
from control_systems import batch, fd_grad, rel, stack

COUNT = 60
TOL = 1e-9
NONSINGULAR = ("generic", "scaled")  # a marginal A (eigenvalues +-jw) makes the Lyapunov equation singular


def _spd(count, n, seed):
    M = np.random.default_rng(seed).standard_normal((count, n, n))
    return M @ np.swapaxes(M, 1, 2) + 0.1 * np.eye(n)


@pytest.mark.parametrize("discrete", [False, True])
def test_lyap_and_sylvester_match_python_control(discrete):
    systems = batch(COUNT, discrete=discrete, seed=400, kinds=NONSINGULAR)
    A, B, C, _ = stack(systems)
    Q = _spd(COUNT, 4, 1)
    if discrete:
        X = jax.jit(jax.vmap(dlyap))(A, Q)
        Qs = 0.5 * np.random.default_rng(2).standard_normal((COUNT, 2, 2))  # Sylvester A X Q^T - X + C = 0
        Y = jax.jit(jax.vmap(dlyap))(A, Qs, B)
    else:
        X = jax.jit(jax.vmap(lyap))(A, Q)
        Qs = np.random.default_rng(2).standard_normal((COUNT, 2, 2)) + 3 * np.eye(2)  # A X + X Q + C = 0
        Y = jax.jit(jax.vmap(lyap))(A, Qs, B)
    for i, (kind, *_) in enumerate(systems):
        Xc = (control.dlyap if discrete else control.lyap)(A[i], Q[i])
        assert rel(X[i], Xc) < TOL, (i, kind, rel(X[i], Xc))
        if discrete:  # python-control's discrete Sylvester needs slycot: SciPy-free check by the Kronecker form
            K = np.eye(8) - np.kron(A[i], Qs[i])
            Yc = np.linalg.solve(K, B[i].reshape(-1)).reshape(4, 2)
        else:
            Yc = control.lyap(A[i], Qs[i], B[i])
        assert rel(Y[i], Yc) < TOL, (i, kind, rel(Y[i], Yc))


@pytest.mark.parametrize("discrete", [False, True])
def test_singular_lyapunov_equation_raises(discrete):
    kind, A, *_ = batch(1, discrete=discrete, seed=5, kinds=("marginal",))[0]
    with pytest.raises(LyapunovError, match="singular"):
        (dlyap if discrete else lyap)(A, np.eye(4))


def test_ctrb_obsv_match_python_control():
    systems = batch(COUNT, seed=500)
    A, B, C, _ = stack(systems)
    Wc = jax.vmap(ctrb)(A, B)
    Wo = jax.vmap(obsv)(A, C)
    for i in range(COUNT):
        assert rel(Wc[i], control.ctrb(A[i], B[i])) < 1e-12
        assert rel(Wo[i], control.obsv(A[i], C[i])) < 1e-12
    assert rel(ctrb(A[0], B[0], t=2), control.ctrb(A[0], B[0], t=2)) < 1e-12


def _scipy_gram(A, B, C, kind, discrete):
    """The equations python-control's gram solves (its SLICOT routines need slycot, not in the test extra)."""
    solve = sla.solve_discrete_lyapunov if discrete else (lambda a, q: sla.solve_continuous_lyapunov(a, -q))
    W = solve(A, B @ B.T) if kind[0] == "c" else solve(A.T, C.T @ C)
    return np.linalg.cholesky(W).T if kind.endswith("f") else W


@pytest.mark.parametrize("discrete", [False, True])
def test_gram_matches_the_equations_python_control_solves(discrete):
    systems = batch(COUNT, discrete=discrete, stable=True, seed=600, kinds=NONSINGULAR)
    dt = 0.1 if discrete else 0.0
    A, B, C, D = stack(systems)
    for kind in ("c", "o", "cf", "of"):
        W = jax.jit(jax.vmap(lambda A, B, C, D: gram(jaxdip.control.StateSpace(A, B, C, D, dt), kind)))(A, B, C, D)
        for i, (k, *_) in enumerate(systems):
            Wc = _scipy_gram(A[i], B[i], C[i], kind, discrete)
            assert rel(W[i], Wc) < TOL, (kind, i, k, rel(W[i], Wc))


def test_gram_matches_python_control_with_slycot():
    pytest.importorskip("slycot")
    for _kind, A, B, C, D in batch(10, stable=True, seed=650, kinds=NONSINGULAR):
        for kind in ("c", "o", "cf", "of"):
            assert rel(gram(ss(A, B, C, D), kind), control.gram(control.ss(A, B, C, D), kind)) < TOL


@pytest.mark.parametrize("discrete", [False, True])
def test_gram_of_unstable_or_marginal_system_raises_like_python_control(discrete):
    dt = 0.1 if discrete else 0.0
    # exactly on the boundary (no similarity: rounding would move the eigenvalues off it either way)
    marginal = np.diag([1.0, 0.5, -0.5, 0.2]) if discrete else np.diag([0.0, -1.0, -2.0, -0.5])
    _, unstable, B, C, D = batch(1, discrete=discrete, stable=False, seed=8)[0]
    for A in (marginal, unstable):
        with pytest.raises(ValueError, match="unstable"):
            control.gram(control.ss(A, B, C, D, dt), "c")
        with pytest.raises(ArgumentError, match="not strictly stable"):
            gram(ss(A, B, C, D, dt), "c")
        W = jax.jit(lambda A: gram(jaxdip.control.StateSpace(A, B, C, D, dt), "o"))(A)
        assert np.all(np.isnan(W))  # under jit: NaN, never a finite wrong Gramian


@pytest.mark.parametrize("kind", ["c", "of"])
def test_gram_gradient_matches_finite_differences(kind):
    k, A, B, C, D = batch(1, stable=True, seed=9)[0]
    Wt = np.random.default_rng(3).standard_normal((4, 4))

    @jax.jit
    def f(A, B):
        return jnp.sum(gram(jaxdip.control.StateSpace(A, B, C, D), kind) * Wt)

    gA, gB = jax.grad(f, argnums=(0, 1))(A, B)
    assert rel(gA, fd_grad(lambda x: float(f(x, B)), A)) < 1e-6
    if kind == "c":
        assert rel(gB, fd_grad(lambda x: float(f(A, x)), B)) < 1e-6


def test_bad_arguments_raise():
    with pytest.raises(ArgumentError, match="Q must be symmetric"):
        lyap(-np.eye(2), np.array([[1.0, 2.0], [0.0, 1.0]]))
    with pytest.raises(ArgumentError, match=r"C must be \(2, 3\)"):
        lyap(-np.eye(2), np.eye(3), np.ones((3, 2)))
    with pytest.raises(ArgumentError, match="type"):
        gram(ss(-np.eye(2), np.ones((2, 1)), np.ones((1, 2))), "x")
