"""LQR / Riccati in pure JAX against python-control and SciPy."""

import jaxdip  # noqa: F401  (enables float64)

import control
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla

from jaxdip.control.designs import dlqr, lqr
from jaxdip.control.riccati import (RiccatiCode, RiccatiError, care, care_checked, dare, dare_checked,
                                   error_if_failed, riccati_status)
from jaxdip.plants import dip
from jaxdip.engine.roles import linearize
from jaxdip.sim.discretize import zoh

# jit once per shape: the functions under test are unchanged, only their dispatch is
jlqr = jax.jit(lqr)
jdlqr = jax.jit(dlqr)
jcare = jax.jit(care)
jdare = jax.jit(dare)

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
    out = []
    for v in ("printed", "lagrangian"):
        A, B = linearize(dip.DIP(variant=v), jnp.zeros(6), 0.0)
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


# ---- failures: reported, and the same verdicts as python-control --------------------------------------------

R1 = np.eye(1)
# the example: the unstable mode 1 is not reachable from B
NONSTAB_C = (np.diag([1.0, -1.0]), np.array([[0.0], [1.0]]), np.eye(2))
NONSTAB_D = (np.diag([1.2, 0.5]), np.array([[0.0], [1.0]]), np.eye(2))
# stabilisable, and (Q, A) not detectable: the unstable mode is not weighted, but it is off the boundary
NONDET_C = (np.diag([1.0, -1.0]), np.array([[1.0], [1.0]]), np.diag([0.0, 1.0]))
NONDET_D = (np.diag([1.2, 0.5]), np.array([[1.0], [1.0]]), np.diag([0.0, 1.0]))
# an unweighted mode on the boundary: no stabilising solution
BOUNDARY_C = (np.diag([0.0, -1.0]), np.array([[1.0], [1.0]]), np.diag([0.0, 1.0]))
BOUNDARY_D = (np.diag([1.0, 0.5]), np.array([[1.0], [1.0]]), np.diag([0.0, 1.0]))


@pytest.mark.parametrize("ours,theirs,case", [(lqr, control.lqr, NONSTAB_C), (dlqr, control.dlqr, NONSTAB_D)],
                         ids=["lqr", "dlqr"])
def test_non_stabilisable_raises_like_python_control(ours, theirs, case):
    A, B, Q = case
    with pytest.raises(np.linalg.LinAlgError):
        theirs(A, B, Q, R1)
    with pytest.raises(RiccatiError, match=r"not stabilisable: the mode 1(\.2)? of A"):
        ours(A, B, Q, R1)
    assert issubclass(RiccatiError, np.linalg.LinAlgError) and issubclass(RiccatiError, ValueError)


def test_non_stabilisable_care_dare_raise_and_checked_variants_report():
    A, B, Q = NONSTAB_C
    with pytest.raises(RiccatiError, match="CARE.*not stabilisable"):
        care(A, B, Q, R1)
    # the old silent answer: a solution of the equation that leaves the mode at 1 in place
    X, code = jax.jit(care_checked)(A, B, Q, R1)
    assert int(code) == RiccatiCode.NOT_STABILISING
    assert np.linalg.norm(A.T @ X + X @ A - X @ B @ B.T @ X + Q) < 1e-12
    A, B, Q = NONSTAB_D
    with pytest.raises(RiccatiError, match="DARE.*not stabilisable"):
        dare(A, B, Q, R1)
    assert int(jax.jit(dare_checked)(A, B, Q, R1)[1]) != RiccatiCode.OK


def test_traced_calls_never_raise_and_codes_vmap():
    A, B, Q = NONSTAB_C
    K, S, E = jax.jit(lqr)(A, B, Q, R1)  # inside jit: no check, no exception
    assert np.real(np.asarray(E)).max() > 0
    assert int(jax.jit(riccati_status)(A, B, Q, R1, S)) == RiccatiCode.NOT_STABILISING
    # a batch with a well-posed and an ill-posed member: one code each
    As = jnp.stack([jnp.diag(jnp.array([-1.0, -1.0])), jnp.asarray(A)])
    _, codes = jax.jit(jax.vmap(care_checked, in_axes=(0, None, None, None)))(As, B, Q, R1)
    assert np.asarray(codes).tolist() == [RiccatiCode.OK, RiccatiCode.NOT_STABILISING]
    assert RiccatiCode.describe(codes[1]).startswith("not stabilising")


def test_error_if_failed_is_opt_in_inside_jit():
    B, Q = NONSTAB_C[1:]
    f = eqx.filter_jit(lambda a: error_if_failed(*care_checked(a, B, Q, R1)))
    with pytest.raises(Exception, match="not stabilising"):
        f(NONSTAB_C[0])
    # a well-posed problem passes through unchanged
    A = np.diag([-1.0, -3.0])
    assert rel(f(A), sla.solve_continuous_are(A, B, Q, R1)) < TOL


@pytest.mark.parametrize("ours,theirs,case", [(lqr, control.lqr, NONDET_C), (dlqr, control.dlqr, NONDET_D)],
                         ids=["lqr", "dlqr"])
def test_non_detectable_but_stabilisable_matches_python_control(ours, theirs, case):
    """python-control returns the stabilising solution here (X >= 0 singular), and so does jaxdip, host or jit.
    For the DARE this is the regularised-doubling fallback: the doubling itself diverges on such problems."""
    A, B, Q = case
    Kc, Sc, Ec = theirs(A, B, Q, R1)
    for f in (ours, jax.jit(ours)):
        K, S, E = f(A, B, Q, R1)
        assert rel(K, Kc) < TOL and rel(S, Sc) < TOL
        assert eig_match(E, Ec) < 1e-8


def test_dare_fallback_gradient_matches_finite_differences():
    A, B, Q = NONDET_D

    def gain(t):
        return dlqr(A + t * np.array([[0.0, 0.3], [0.2, -0.1]]), B, Q, R1)[0]

    g = jax.jacfwd(gain)(0.0)
    h = 1e-6
    fd = (control.dlqr(A + h * np.array([[0.0, 0.3], [0.2, -0.1]]), B, Q, R1)[0]
          - control.dlqr(A - h * np.array([[0.0, 0.3], [0.2, -0.1]]), B, Q, R1)[0]) / (2 * h)
    assert rel(g, fd) < 1e-6, rel(g, fd)


@pytest.mark.parametrize("ours,theirs,case,discrete", [(lqr, control.lqr, BOUNDARY_C, False),
                                                       (dlqr, control.dlqr, BOUNDARY_D, True)],
                         ids=["lqr", "dlqr"])
def test_unobservable_boundary_mode_raises_where_python_control_returns_marginal_gain(ours, theirs, case, discrete):
    """A documented difference: no stabilising solution exists; python-control (SciPy's Schur solver) returns a
    gain that leaves the mode on the boundary, jaxdip raises and names it."""
    A, B, Q = case
    _, _, Ec = theirs(A, B, Q, R1)
    margin = np.abs(Ec).max() - 1 if discrete else np.real(Ec).max()
    assert abs(margin) < 1e-12
    with pytest.raises(RiccatiError, match="unobservable from Q"):
        ours(A, B, Q, R1)


def test_r_not_positive_definite_raises():
    with pytest.raises(ValueError, match="singular"):
        control.lqr(np.eye(2), np.eye(2), np.eye(2), np.zeros((2, 2)))
    with pytest.raises(RiccatiError, match="R is not positive definite"):
        lqr(np.eye(2), np.eye(2), np.eye(2), np.zeros((2, 2)))


def test_too_few_iterations_are_reported():
    _, A, B, Q, R = CONT[2]
    with pytest.raises(RiccatiError, match="did not converge.*raise sign_iters"):
        care(A, B, Q, R, 2, 0)
    assert int(jax.jit(care_checked, static_argnums=(4, 5))(A, B, Q, R, 2, 0)[1]) == RiccatiCode.NOT_CONVERGED
    _, A, B, Q, R = DISC[3]
    with pytest.raises(RiccatiError, match="did not converge.*raise iters"):
        dare(A, B, Q, R, 2)
    assert int(jax.jit(dare_checked, static_argnums=4)(A, B, Q, R, 2)[1]) == RiccatiCode.NOT_CONVERGED


@pytest.mark.parametrize("name,A,B,Q,R,discrete", [c + (False,) for c in CONT] + [c + (True,) for c in DISC],
                         ids=[c[0] for c in CONT] + [c[0] + "-d" for c in DISC])
def test_well_posed_host_path_passes_its_check(name, A, B, Q, R, discrete):
    """Eager calls (checked on the host: the call raises on a failed check) accept every well-posed system and
    agree with python-control."""
    f, theirs = (dlqr, control.dlqr) if discrete else (lqr, control.lqr)
    K, S, E = f(A, B, Q, R)
    Kc, Sc, _ = theirs(A, B, Q, R)
    assert rel(K, Kc) < TOL and rel(S, Sc) < TOL


@pytest.mark.parametrize("discrete", [False, True], ids=["care", "dare"])
def test_checked_variant_keeps_the_implicit_gradient(discrete):
    name, A, B, Q, R = (DISC if discrete else CONT)[2]
    solve, checked = (dare, dare_checked) if discrete else (care, care_checked)

    def loss(f, a):
        X = f(a, B, Q, R)
        X = X[0] if isinstance(X, tuple) else X
        return jnp.sum(X ** 2)

    g1 = jax.jit(jax.grad(lambda a: loss(solve, a)))(A)
    g2 = jax.jit(jax.grad(lambda a: loss(checked, a)))(A)
    assert np.array_equal(np.asarray(g1), np.asarray(g2))
