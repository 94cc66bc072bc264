"""LQR / Riccati / Lyapunov in pure JAX against python-control and SciPy."""

import jaxdip  # noqa: F401  (enables float64)

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla

from jaxdip.control.riccati import care, dare, dlqr, lqr, lyap
from jaxdip.plants import dip
from jaxdip.sim.discretize import linearize, zoh

# jit once per shape: the functions under test are unchanged, only their dispatch is
jlqr = jax.jit(lqr)
jdlqr = jax.jit(dlqr)
jcare = jax.jit(care)
jdare = jax.jit(dare)
jlyap = jax.jit(lyap)

TOL = 1e-9

Q_DIP = np.diag([30.0, 350.0, 100.0, 0.0, 0.0, 0.0])  # xc, alpha, theta weighted; velocities not
R_DIP = np.array([[0.1]])


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def eig_match(E1, E2):
    """Largest distance from an eigenvalue of one set to the nearest of the other, relative to the spectrum size."""
    E1, E2 = np.asarray(E1), np.asarray(E2)
    assert E1.shape == E2.shape
    d = np.abs(E1[:, None] - E2[None, :])
    return max(d.min(axis=1).max(), d.min(axis=0).max()) / max(1.0, np.abs(E2).max())


# ---- systems ----------------------------------------------------------------------------------------------


def _dip_continuous():
    p = dip.default_params()
    out = []
    for v in ("printed", "lagrangian"):
        A, B = jax.jit(linearize, static_argnums=0)(dip.make(v).f, p, jnp.zeros(6), 0.0)
        out.append((f"dip-{v}", np.asarray(A), np.asarray(B), Q_DIP, R_DIP))
    return out


def _random_system(seed, m, kind, discrete=False):
    rng = np.random.default_rng(seed)
    n = 6
    A = rng.standard_normal((n, n))
    if discrete:
        # spectral radius 1.2: unstable open loop, so the doubling has work to do
        A = 1.2 * A / np.abs(np.linalg.eigvals(A)).max()
    B = rng.standard_normal((n, m))
    if kind == "stabilisable":
        # two stable modes the input cannot reach, hidden by a random similarity transform
        if discrete:
            A[:4, :4] *= 1.2 / np.abs(np.linalg.eigvals(A[:4, :4])).max()
        A[4:, :4] = 0.0
        A[4:, 4:] = np.array([[0.5, 0.6], [-0.6, 0.5]]) if discrete else np.array([[-1.0, 2.0], [-2.0, -1.0]])
        B[4:] = 0.0
        T = np.linalg.qr(rng.standard_normal((n, n)))[0]
        A, B = T @ A @ T.T, T @ B
    if kind == "psd-q":
        C = rng.standard_normal((2, n))
        Q = C.T @ C  # rank 2, (A, C) observable generically
    else:
        M = rng.standard_normal((n, n))
        Q = M @ M.T / n
    Rm = rng.standard_normal((m, m))
    R = Rm @ Rm.T + 0.1 * np.eye(m)
    return A, B, Q, R


RANDOM = [(f"random-{k}-m{m}-s{s}", s, m, k) for s, m, k in [
    (0, 1, "generic"), (1, 2, "generic"), (2, 1, "psd-q"), (3, 2, "psd-q"), (4, 1, "stabilisable"),
    (5, 2, "stabilisable")]]


def _continuous_systems():
    out = _dip_continuous()
    for name, s, m, k in RANDOM:
        out.append((name, *_random_system(s, m, k)))
    return out


def _discrete_systems():
    out = []
    for name, A, B, Q, R in _dip_continuous():
        d = zoh(A, B, 1e-3)
        out.append((f"{name}-zoh1ms", np.asarray(d.Phi), np.asarray(d.W), Q, R))
    for name, s, m, k in RANDOM:
        A, B, Q, R = _random_system(s, m, k, discrete=True)
        assert np.abs(np.linalg.eigvals(A)).max() > 1.0
        out.append((name, A, B, Q, R))
    return out


CONT = _continuous_systems()
DISC = _discrete_systems()


# ---- LQR vs python-control --------------------------------------------------------------------------------


@pytest.mark.parametrize("name,A,B,Q,R", CONT, ids=[c[0] for c in CONT])
def test_lqr_matches_python_control(name, A, B, Q, R):
    K, S, E = jlqr(A, B, Q, R)
    Kc, Sc, Ec = control.lqr(A, B, Q, R)
    assert rel(K, Kc) < TOL, rel(K, Kc)
    assert rel(S, Sc) < TOL, rel(S, Sc)
    assert eig_match(E, Ec) < 1e-8
    assert np.all(np.real(np.asarray(E)) < 0)
    # E are the eigenvalues of A - B K
    assert eig_match(np.linalg.eigvals(A - B @ np.asarray(K)), E) < 1e-10
    assert np.allclose(S, np.asarray(S).T, rtol=0, atol=1e-14 * np.abs(S).max())


@pytest.mark.parametrize("name,A,B,Q,R", DISC, ids=[c[0] for c in DISC])
def test_dlqr_matches_python_control(name, A, B, Q, R):
    K, S, E = jdlqr(A, B, Q, R)
    Kc, Sc, Ec = control.dlqr(A, B, Q, R)
    assert rel(K, Kc) < TOL, rel(K, Kc)
    assert rel(S, Sc) < TOL, rel(S, Sc)
    assert eig_match(E, Ec) < 1e-8
    assert np.all(np.abs(np.asarray(E)) < 1.0)
    # DARE residual, relative to the size of its terms
    S = np.asarray(S)
    SB = S @ B
    res = A.T @ S @ A - S - A.T @ SB @ np.linalg.solve(R + B.T @ SB, SB.T @ A) + Q
    assert np.linalg.norm(res) < 1e-12 * (np.linalg.norm(A.T @ S @ A) + np.linalg.norm(S) + np.linalg.norm(Q))


def test_dip_lqr_published_shape():
    """The DIP gain drives every state: a sanity check that cannot pass with a zero or transposed K."""
    name, A, B, Q, R = CONT[0]
    K, _, _ = jlqr(A, B, Q, R)
    assert K.shape == (1, 6)
    assert np.all(np.abs(np.asarray(K)) > 1e-3)


# ---- CARE residual and Lyapunov ---------------------------------------------------------------------------


@pytest.mark.parametrize("name,A,B,Q,R", CONT, ids=[c[0] for c in CONT])
def test_care_residual(name, A, B, Q, R):
    X = np.asarray(jcare(A, B, Q, R))
    G = B @ np.linalg.solve(R, B.T)
    res = A.T @ X + X @ A - X @ G @ X + Q
    scale = 2 * np.linalg.norm(A.T @ X) + np.linalg.norm(X @ G @ X) + np.linalg.norm(Q)
    assert np.linalg.norm(res) < 1e-12 * scale, np.linalg.norm(res) / scale
    # the stabilising solution: PSD and A - G X Hurwitz
    assert np.linalg.eigvalsh(X).min() > -1e-10 * np.abs(X).max()
    assert np.real(np.linalg.eigvals(A - G @ X)).max() < 0
    # and the same matrix as SciPy's Schur-method solver
    assert rel(X, sla.solve_continuous_are(A, B, Q, R)) < TOL


@pytest.mark.parametrize("name,A,B,Q,R", DISC[:1] + DISC[2:4], ids=[c[0] for c in DISC[:1] + DISC[2:4]])
def test_dare_matches_scipy(name, A, B, Q, R):
    assert rel(jdare(A, B, Q, R), sla.solve_discrete_are(A, B, Q, R)) < TOL


@pytest.mark.parametrize("seed", range(4))
def test_lyap_matches_scipy(seed):
    rng = np.random.default_rng(100 + seed)
    n = 6
    A = rng.standard_normal((n, n))
    A = A - (np.real(np.linalg.eigvals(A)).max() + 0.5) * np.eye(n)  # Hurwitz
    M = rng.standard_normal((n, n))
    Q = M @ M.T
    X = np.asarray(jlyap(A, Q))
    # ours: A^T X + X A + Q = 0; SciPy: a x + x a^H = q
    Xs = sla.solve_continuous_lyapunov(A.T, -Q)
    assert rel(X, Xs) < 1e-12, rel(X, Xs)
    assert np.linalg.norm(A.T @ X + X @ A + Q) < 1e-12 * np.linalg.norm(Q) * max(1.0, np.linalg.norm(X))
    assert np.linalg.eigvalsh(X).min() > 0  # Q > 0 and A Hurwitz give X > 0
