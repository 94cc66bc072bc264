"""zoh and linearize against independent references: SciPy's expm / cont2discrete and finite differences."""

import jaxdip  # noqa: F401  (enables float64)

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla
import scipy.signal as ssig

from jaxdip.plants import dip
from jaxdip.engine.roles import linearize
from jaxdip.sim.discretize import zoh

TOL = 1e-12


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def _random_systems():
    # Shapes are kept to (6, 1) and (6, 2), the DIP's, so the suite compiles expm for few shapes.
    rng = np.random.default_rng(20240611)
    systems = []
    for m, h in [(1, 0.1), (1, 1e-3), (2, 0.2), (2, 0.05)]:
        systems.append((f"random-m{m}-h{h:g}", rng.standard_normal((6, 6)), rng.standard_normal((6, m)), h))
    # singular A: an integrator chain, a rank-deficient random matrix, and the zero matrix
    systems.append(("integrator-chain", np.diag(np.ones(5), 1), np.eye(6)[:, -1:], 0.1))
    U = rng.standard_normal((6, 6))
    Asing = U @ np.diag([0.0, 0.0, -1.5, 0.7, 2.0, -0.3]) @ np.linalg.inv(U)
    systems.append(("rank-4-of-6", Asing, rng.standard_normal((6, 2)), 0.1))
    systems.append(("zero-A", np.zeros((6, 6)), rng.standard_normal((6, 1)), 0.3))
    return systems


def _dip_systems():
    out = []
    for v in ("printed", "lagrangian"):
        A, B = linearize(dip.DIP(variant=v), jnp.zeros(6), 0.0)
        out.append((f"dip-{v}", np.asarray(A), np.asarray(B), 1e-3))
    return out


SYSTEMS = _random_systems() + _dip_systems()


@pytest.mark.parametrize("name,A,B,h", SYSTEMS, ids=[s[0] for s in SYSTEMS])
def test_zoh_matches_scipy(name, A, B, h):
    n, m = B.shape
    d = zoh(A, B, h)

    # reference 1: SciPy's (independent) expm of the augmented matrix
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = sla.expm(M * h)
    assert rel(d.Phi, E[:n, :n]) < TOL
    assert rel(d.W, E[:n, n:]) < TOL

    # reference 2: scipy.signal.cont2discrete
    Ad, Bd, *_ = ssig.cont2discrete((A, B, np.eye(n), np.zeros((n, m))), h, method="zoh")
    assert rel(d.Phi, Ad) < TOL
    assert rel(d.W, Bd) < TOL

    # Phi_inv: e^{-Ah} from SciPy, and a numerical inverse of Phi
    assert rel(d.Phi_inv, sla.expm(-A * h)) < TOL
    assert rel(d.Phi_inv, np.linalg.inv(np.asarray(d.Phi))) < TOL
    assert np.linalg.norm(np.asarray(d.Phi_inv) @ np.asarray(d.Phi) - np.eye(n)) < TOL


def test_zoh_singular_A_integrator_closed_form():
    """Chain of 6 integrators (A nilpotent, singular): Phi = sum_k (A h)^k / k!, W_i = h^(6-i) / (6-i)! exactly."""
    from math import factorial

    h = 0.37
    n = 6
    N = np.diag(np.ones(n - 1), 1)
    d = zoh(N, np.eye(n)[:, -1:], h)
    Phi = sum(np.linalg.matrix_power(N * h, k) / factorial(k) for k in range(n))
    W = np.array([[h ** (n - i) / factorial(n - i)] for i in range(n)])
    Phi_inv = sum(np.linalg.matrix_power(-N * h, k) / factorial(k) for k in range(n))
    np.testing.assert_allclose(d.Phi, Phi, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(d.W, W, rtol=1e-14, atol=1e-17)
    np.testing.assert_allclose(d.Phi_inv, Phi_inv, rtol=1e-14, atol=1e-15)


# ---- linearize vs central finite differences --------------------------------------------------------------


def central_fd(f, x0, u0, step=1e-6):
    """Jacobians by central differences with a per-coordinate step ~1e-6 (scaled by the magnitude)."""
    x0 = np.asarray(x0, dtype=float)
    u0 = np.atleast_1d(np.asarray(u0, dtype=float))
    fx = lambda x, u: np.asarray(f(jnp.asarray(x), jnp.asarray(u)))  # noqa: E731
    n, m = x0.size, u0.size
    A = np.zeros((n, n))
    B = np.zeros((n, m))
    for j in range(n):
        dj = step * max(1.0, abs(x0[j]))
        e = np.zeros(n)
        e[j] = dj
        A[:, j] = (fx(x0 + e, u0) - fx(x0 - e, u0)) / (2 * dj)
    for j in range(m):
        dj = step * max(1.0, abs(u0[j]))
        e = np.zeros(m)
        e[j] = dj
        B[:, j] = (fx(x0, u0 + e) - fx(x0, u0 - e)) / (2 * dj)
    return A, B


POINTS = {
    "origin": (np.zeros(6), 0.0),
    "random": (
        np.array([0.12, 0.31, -0.47, 0.25, -1.3, 2.1]),  # a generic state: every trig term is non-trivial
        1.7,
    ),
}


@pytest.mark.parametrize("variant", ["printed", "lagrangian"])
@pytest.mark.parametrize("point", list(POINTS))
def test_linearize_vs_finite_differences(variant, point):
    plant = dip.DIP(variant=variant)
    f = jax.jit(lambda x, u: plant.vector_field(x, u))
    x0, u0 = POINTS[point]
    A, B = linearize(plant, x0, u0)
    Afd, Bfd = central_fd(f, x0, u0)
    assert A.shape == (6, 6) and B.shape == (6, 1)
    assert rel(A, Afd) < 1e-7, rel(A, Afd)
    assert rel(B, Bfd) < 1e-7, rel(B, Bfd)
    # the test can fail: a Jacobian at the wrong point is far off
    if point == "random":
        A0, _ = linearize(plant, np.zeros(6), 0.0)
        assert rel(A0, Afd) > 1e-3


def test_linearize_dip_structure():
    """Kinematic rows are [0 I]; the input reaches only the accelerations."""
    for v in ("printed", "lagrangian"):
        A, B = linearize(dip.DIP(variant=v), np.zeros(6), 0.0)
        np.testing.assert_array_equal(np.asarray(A)[:3], np.hstack([np.zeros((3, 3)), np.eye(3)]))
        np.testing.assert_array_equal(np.asarray(B)[:3], 0.0)
        # the cart position is an integrator: A is singular
        assert np.allclose(np.asarray(A)[:, 0], 0.0)
