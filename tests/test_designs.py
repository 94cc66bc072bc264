"""lqr/dlqr with a cross weight, integral action, lqe/dlqe against python-control 0.10 (60 random systems each:
generic, marginally stable, badly scaled), the failures python-control raises on, and gradients against
finite differences."""

import jaxdip  # noqa: F401  (enables float64)

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.control import RiccatiError, dlqe, dlqr, lqe, lqi, lqr, riccati_status
from jaxdip.engine.checks import ArgumentError
from control_systems import batch, eig_match, fd_grad, rel, stack, weights

COUNT = 60
TOL = 1e-9


def _weights(count, n, m):
    Q, R, N = (np.stack(w) for w in zip(*(weights(i, n, m) for i in range(count))))
    return Q, R, N


@pytest.mark.parametrize("discrete", [False, True])
def test_lqr_with_cross_weight_matches_python_control(discrete):
    systems = batch(COUNT, discrete=discrete, seed=100 if discrete else 0)
    A, B, _, _ = stack(systems)
    Q, R, N = _weights(COUNT, 4, 2)
    design, ref = (dlqr, control.dlqr) if discrete else (lqr, control.lqr)
    K, S, E = jax.jit(jax.vmap(design))(A, B, Q, R, N)
    codes = jax.vmap(lambda A, B, Q, R, N, S: riccati_status(A - B @ jnp.linalg.solve(R, N.T), B,
                                                             Q - N @ jnp.linalg.solve(R, N.T), R, S,
                                                             discrete=discrete))(A, B, Q, R, N, S)
    assert np.all(np.asarray(codes) == 0)
    worse = []
    for i, (kind, *_) in enumerate(systems):
        Kc, Sc, Ec = ref(A[i], B[i], Q[i], R[i], N[i])
        if rel(K[i], Kc) > TOL or rel(S[i], Sc) > TOL:
            # an ill-conditioned problem (cond S ~ 1e6) on which python-control (SciPy) is the less accurate one
            ours, theirs = (_residual(A[i], B[i], Q[i], R[i], N[i], X, discrete) for X in (S[i], Sc))
            assert ours < 1e-2 * theirs, (i, kind, rel(K[i], Kc), ours, theirs)
            worse.append(i)
            continue
        assert eig_match(E[i], Ec) < 1e-8
    assert len(worse) <= COUNT // 30, worse


def _residual(A, B, Q, R, N, X, discrete):
    """Relative residual of the Riccati equation with cross weight N, in NumPy."""
    X = np.asarray(X)
    if discrete:
        K = np.linalg.solve(R + B.T @ X @ B, B.T @ X @ A + N.T)
        res = A.T @ X @ A - X - (A.T @ X @ B + N) @ K + Q
    else:
        K = np.linalg.solve(R, B.T @ X + N.T)
        res = A.T @ X + X @ A - (X @ B + N) @ K + Q
    return np.linalg.norm(res) / np.linalg.norm(X)


@pytest.mark.parametrize("discrete", [False, True])
def test_lqi_matches_python_control_integral_action(discrete):
    systems = batch(COUNT, discrete=discrete, seed=200)
    A, B, C, _ = stack(systems)
    C = C[:, :1]  # one integrated output
    Q = np.stack([np.diag(np.random.default_rng(i).uniform(0.5, 2.0, 5)) for i in range(COUNT)])
    R = np.stack([np.eye(2)] * COUNT)
    dt = 0.1 if discrete else 0.0
    K, S, _ = jax.jit(jax.vmap(lambda A, B, C, Q, R: lqi(A, B, C, Q, R, dt=dt)))(A, B, C, Q, R)
    ref = control.dlqr if discrete else control.lqr
    for i, (kind, *_) in enumerate(systems):
        Kc, Sc, _ = ref(A[i], B[i], Q[i], R[i], integral_action=C[i])
        assert rel(K[i], Kc) < TOL, (i, kind, rel(K[i], Kc))
        assert rel(S[i], Sc) < TOL, (i, kind, rel(S[i], Sc))


@pytest.mark.parametrize("discrete", [False, True])
def test_lqe_matches_python_control(discrete):
    systems = batch(COUNT, m=3, discrete=discrete, seed=300)
    A, G, C, _ = stack(systems)
    rng = np.random.default_rng(3)
    QN = np.stack([np.diag(rng.uniform(0.1, 3.0, 3)) for _ in range(COUNT)])
    M = rng.standard_normal((COUNT, 2, 2))
    RN = M @ np.swapaxes(M, 1, 2) + 0.5 * np.eye(2)
    design, ref = (dlqe, control.dlqe) if discrete else (lqe, control.lqe)
    L, P, E = jax.jit(jax.vmap(design))(A, G, C, QN, RN)
    for i, (kind, *_) in enumerate(systems):
        # python-control checks G QN G^T for symmetry to a tolerance rounding breaks (it raises on 46 of these 60);
        # it gets the same problem as G = I and QN = the symmetrised G QN G^T (a product with I is exact)
        W = G[i] @ QN[i] @ G[i].T
        Lc, Pc, Ec = ref(A[i], np.eye(4), C[i], 0.5 * (W + W.T), RN[i])
        assert rel(L[i], Lc) < TOL, (i, kind, rel(L[i], Lc))
        assert rel(P[i], Pc) < TOL, (i, kind, rel(P[i], Pc))
        assert eig_match(E[i], Ec) < 1e-8


def test_host_path_equals_vmapped_path():
    kind, A, B, C, _ = batch(1, seed=7)[0]
    Q, R, N = weights(7, 4, 2)
    K1 = lqr(A, B, Q, R, N)[0]
    K2 = jax.vmap(lqr)(*(x[None] for x in (A, B, Q, R, N)))[0][0]
    assert rel(K1, K2) < 1e-14


# ---- failures ------------------------------------------------------------------------------------------------


def _uncontrollable():
    A = np.diag([1.0, -2.0, 0.5])  # the unstable modes 1 and 0.5: B reaches only the first
    B = np.array([[1.0], [1.0], [0.0]])
    return A, B


@pytest.mark.parametrize("discrete", [False, True])
def test_not_stabilisable_with_cross_weight_raises_like_python_control(discrete):
    A, B = _uncontrollable()
    if discrete:
        A = A + np.diag([0.5, 2.5, 1.0])  # eigenvalues 1.5, 0.5, 1.5
    Q, R, N = np.eye(3), np.eye(1), 0.1 * np.ones((3, 1))
    with pytest.raises(np.linalg.LinAlgError):
        (control.dlqr if discrete else control.lqr)(A, B, Q, R, N)
    with pytest.raises(RiccatiError, match="not stabilisable"):
        (dlqr if discrete else lqr)(A, B, Q, R, N)


def test_undetectable_estimator_raises_like_python_control():
    A, B = _uncontrollable()
    C, G = B.T, np.eye(3)  # (C, A) does not see the unstable mode 0.5
    with pytest.raises(np.linalg.LinAlgError):
        control.lqe(A, G, C, np.eye(3), np.eye(1))
    with pytest.raises(RiccatiError):
        lqe(A, G, C, np.eye(3), np.eye(1))


def test_indefinite_joint_weight_raises():
    kind, A, B, C, _ = batch(1, seed=1)[0]
    with pytest.raises(ArgumentError, match=r"\[\[Q, N\], \[N\^T, R\]\].*indefinite"):
        lqr(A, B, np.eye(4), np.eye(2), 10 * np.ones((4, 2)))
    with pytest.raises(ArgumentError, match="N must be"):
        lqr(A, B, np.eye(4), np.eye(2), np.ones((2, 4)))


# ---- gradients -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("discrete", [False, True])
def test_lqr_with_cross_weight_gradient_matches_finite_differences(discrete):
    kind, A, B, _, _ = batch(1, discrete=discrete, seed=11)[0]
    Q, R, N = weights(11, 4, 2)
    W = np.random.default_rng(0).standard_normal((2, 4))
    design = dlqr if discrete else lqr

    @jax.jit
    def f(A, N):
        return jnp.sum(design(A, B, Q, R, N)[0] * W)

    gA, gN = jax.grad(f, argnums=(0, 1))(A, N)
    assert rel(gA, fd_grad(lambda x: float(f(x, N)), A)) < 1e-6
    assert rel(gN, fd_grad(lambda x: float(f(A, x)), N)) < 1e-6


def test_lqe_gradient_matches_finite_differences():
    kind, A, G, C, _ = batch(1, m=3, seed=12)[0]
    QN, RN = np.diag([1.0, 2.0, 0.5]), np.eye(2)
    W = np.random.default_rng(1).standard_normal((4, 2))

    @jax.jit
    def f(A, QN):
        return jnp.sum(lqe(A, G, C, QN, RN)[0] * W)

    gA, gQ = jax.grad(f, argnums=(0, 1))(A, QN)
    assert rel(gA, fd_grad(lambda x: float(f(x, QN)), A)) < 1e-6
    assert rel(gQ, fd_grad(lambda x: float(f(A, x)), QN)) < 1e-6
