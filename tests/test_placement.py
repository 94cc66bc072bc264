"""place/acker against python-control 0.10 on 60 random systems: single input, the gain itself (it is unique);
several inputs, the closed-loop poles (python-control's Tits-Yang gain is one of many). Failures and gradients."""

import jaxdip  # noqa: F401  (enables float64)

from fractions import Fraction

import control
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.control import acker, place
from jaxdip.engine.checks import ArgumentError
from control_systems import batch, eig_match, fd_grad, rel, stack

COUNT = 60
TOL = 1e-9


def _poles(count, n, seed):
    """Real and complex-pair poles (n = 4: two real and a pair, or two pairs)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        a, b = -rng.uniform(0.5, 3.0, 2)
        w = rng.uniform(0.2, 2.0, 2)
        out.append(np.array([a + 1j * w[0], a - 1j * w[0], b, -rng.uniform(0.5, 3.0)]) if i % 2 else
                   np.array([a + 1j * w[0], a - 1j * w[0], b + 1j * w[1], b - 1j * w[1]]))
    return np.stack(out)


def _exact_ackermann(A, B, p):
    """Ackermann's gain in exact rational arithmetic (the poles' polynomial rounded once, as every method has it)."""
    n = len(A)
    Am = [[Fraction(x) for x in row] for row in A]
    cols, v = [], [Fraction(x) for x in B[:, 0]]
    for _ in range(n):
        cols.append(v)
        v = [sum(Am[r][k] * v[k] for k in range(n)) for r in range(n)]
    Pm = [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]
    for c in np.poly(p).real[1:]:  # Horner
        Pm = [[sum(Pm[i][k] * Am[k][j] for k in range(n)) + (Fraction(c) if i == j else 0) for j in range(n)]
              for i in range(n)]
    M = [[cols[j][r] for j in range(n)] + Pm[r] for r in range(n)]  # [ctrb | phi(A)], Gauss-Jordan
    for col in range(n):
        piv = next(r for r in range(col, n) if M[r][col] != 0)
        M[col], M[piv] = M[piv], M[col]
        M[col] = [x / M[col][col] for x in M[col]]
        for r in range(n):
            if r != col and M[r][col] != 0:
                f = M[r][col]
                M[r] = [a - f * b for a, b in zip(M[r], M[col])]
    return np.array([float(x) for x in M[n - 1][n:]])


def test_single_input_gain_matches_python_control():
    systems = batch(COUNT, m=1, seed=700)
    A, B, _, _ = stack(systems)
    P = _poles(COUNT, 4, 1)
    K = jax.jit(jax.vmap(place))(A, B, P)
    Ka = jax.jit(jax.vmap(acker))(A, B, P)
    worse = []
    for i, (kind, *_) in enumerate(systems):
        Kc = control.place(A[i], B[i], P[i])
        Kx = _exact_ackermann(A[i], B[i], P[i])
        assert rel(K[i][0], Kx) < TOL, (i, kind, rel(K[i][0], Kx))
        assert rel(Ka[i], Kx) < TOL, (i, kind, rel(Ka[i], Kx))
        assert rel(Ka[i], control.acker(A[i], B[i], P[i])) < TOL, (i, kind)
        if rel(K[i], Kc) > TOL:  # then python-control's gain is the one off the exact gain
            assert rel(Kc[0], Kx) > 10 * rel(K[i][0], Kx), (i, kind, rel(K[i], Kc))
            worse.append(i)
        assert eig_match(np.linalg.eigvals(A[i] - B[i] @ np.asarray(K[i])), P[i]) < 1e-8
    assert len(worse) <= 2, worse


@pytest.mark.parametrize("m", [2, 3])
def test_multi_input_places_the_poles_python_control_places(m):
    systems = batch(COUNT, m=m, seed=800 + m)
    A, B, _, _ = stack(systems)
    P = _poles(COUNT, 4, m)
    P[::3, 2:] = -1.5  # a real pole repeated (up to rank B times is allowed)
    K = jax.jit(jax.vmap(place))(A, B, P)
    for i, (kind, *_) in enumerate(systems):
        Kc = control.place(A[i], B[i], P[i])
        ours = eig_match(np.linalg.eigvals(A[i] - B[i] @ np.asarray(K[i])), P[i])
        theirs = eig_match(np.linalg.eigvals(A[i] - B[i] @ Kc), P[i])
        # a repeated pole moves by the square root of the rounding error, for python-control as for jaxdip
        tol = 1e-6 if i % 3 == 0 else TOL
        assert ours < tol, (i, kind, ours, theirs)


def test_failures_raise_like_python_control():
    A = np.diag([1.0, 2.0, 3.0])
    B = np.array([[1.0], [1.0], [0.0]])  # the mode 3 is not reachable
    with pytest.raises(ValueError):
        control.place(A, B, [-1, -2, -3])
    with pytest.raises(ValueError):
        control.acker(A, B, [-1, -2, -3])
    for f in (place, acker):
        with pytest.raises(ArgumentError, match="not reachable"):
            f(A, B, [-1.0, -2.0, -3.0])
    A = np.array([[1.0, 1.0, 0.0], [0.0, 2.0, 1.0], [0.0, 0.0, 3.0]])
    B2 = np.eye(3)[:, 1:]
    with pytest.raises(ValueError, match="repeated"):
        control.place(A, B2, [-1, -1, -1])
    with pytest.raises(ArgumentError, match="repeated 3 times, more than rank"):
        place(A, B2, [-1.0, -1.0, -1.0])
    with pytest.raises(ValueError):
        control.place(A, B2, [-1 + 1j, -1 - 2j, -3])
    with pytest.raises(ArgumentError, match="conjugate pairs"):
        place(A, B2, [-1 + 1j, -1 - 2j, -3])
    with pytest.raises(ArgumentError, match="single column"):
        acker(A, B2, [-1.0, -2.0, -3.0])


@pytest.mark.parametrize("m", [1, 2])
def test_place_gradient_matches_finite_differences(m):
    kind, A, B, _, _ = batch(1, m=m, seed=900 + m)[0]
    p = np.array([-1.0, -2.0, -0.5, -3.0])
    W = np.random.default_rng(0).standard_normal((m, 4))

    @jax.jit
    def f(A, p):
        return jnp.sum(place(A, B, p) * W)

    gA, gp = jax.grad(f, argnums=(0, 1))(A, p)
    assert rel(gA, fd_grad(lambda x: float(f(x, p)), A)) < 1e-6
    assert rel(gp, fd_grad(lambda x: float(f(A, x)), p)) < 1e-6
