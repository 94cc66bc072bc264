"""King's thesis, chapter 2: Propositions 2.3.1, 2.3.3 and 2.5.2-2.5.5 (projection and relaxed projection control
of discrete-time systems), checked on the thesis's systems against independent computations.

Systems: the 2-D linear (§2.7.1) and nonlinear (§2.7.2) examples with the thesis's search results v (P of (2.19),
s = 1e6), and the DIP linearised at upright, discretised exactly (ZOH, 1 ms), with a P of (2.19) whose hyperplane
normal places the on-surface poles at -1 ± i, -3, -5, -8 (its spectral radius under projection control is 0.999:
stabilising in the sense of Definition 2.5.1). References: SciPy null spaces, Cholesky factors, generalised
symmetric eigenvalues, and the closed loops (2.16) written again in NumPy.

Notation: Q = B (B^T P B)^-1 B^T P (the P-orthogonal projector onto R(B)), T = (I - Q) A (projection control's
closed loop), c_k = 1/(1 + gamma_k); (2.16) is x_{k+1} = T x_k + c_k Q x_k. For Props 2.5.3-2.5.5, sigma is
taken halfway between the spectral radius of T and 1, and M = sup_k ||T^k|| / sigma^k (computed over powers
until the ratio has fallen a thousandfold), so that ||T^k y|| <= M sigma^k ||y||.

What was derived again. Splitting x_k = v_k + z_k (v in the P-orthogonal complement of R(B), z = Q x), Q T = 0
gives z_k = (c_0 ... c_{k-1}) z_0 and

    x_k = T^k x_0 + sum_{m=0}^{k-1} (c_0 ... c_m) T^{k-1-m} z_0.

The printed (2.17) has T^k v_0 in place of T^k x_0 (it drops T^k z_0, which is not zero), so the bounds are
asserted in the form that follows from this one: ||x_k|| <= M sigma^k ||x_0|| + M ||z_0|| sum_m (c_0 .. c_m)
sigma^(k-1-m), hence (2.5.3) ||x_k|| <= M (||x_0|| + ||z_0||/(1 - sigma)) and (2.5.4, c_k < eta)
||x_k|| <= M sigma^k ||x_0|| + M ||z_0|| k r^k with r = max(sigma, eta). The printed (2.5.3) squares the norms
(||x_k||^2 <= M (||v_0||^2 + ||z_0||^2/(1 - sigma))), which does not follow from ||T^k y|| <= M sigma^k ||y||;
test_prop_2_5_3_bounded says whether it held on the same trajectories.
"""

import numpy as np
import scipy.linalg as sla

import jax.numpy as jnp

import jaxdip  # noqa: F401  (float64)
from jaxdip.control.projection import (
    projected_closed_loop, projection, relaxed_closed_form, relaxed_discrete, state_weight,
)
from jaxdip.control.spd import P_v, surface_normal
from jaxdip.plants import dip, examples2d
from jaxdip.engine.roles import linearize


def _linear_example():
    prm = examples2d.Linear()
    return np.asarray(prm.A), np.asarray(prm.B).reshape(2, 1), np.asarray(P_v(jnp.array([-0.9975, -0.07]), 1e6))


def _dip_example():
    A, B = [np.asarray(m) for m in linearize(dip.DIP(), jnp.zeros(6), jnp.zeros(1))]
    M = np.zeros((7, 7))
    M[:6, :6], M[:6, 6:] = A, B
    E = sla.expm(M * 1e-3)
    c = np.asarray(surface_normal(A, B, np.array([-1.0 + 1j, -1.0 - 1j, -3.0, -5.0, -8.0])))
    return E[:6, :6], E[:6, 6:], np.asarray(P_v(c, 1e9))


SYSTEMS = {"linear 2.7.1": _linear_example, "DIP 1 ms": _dip_example}


def _nonlinear_fg(x):
    """f and g of §2.7.2 in NumPy (the jaxdip plant's parameters)."""
    p = examples2d.Nonlinear()
    f = np.array([p.a * np.sin(p.w * x[0]) + p.c * x[1], p.d * x[0] ** 2 + p.e * x[1]])
    return f, np.array([[0.0], [p.g0 + p.g1 * np.cos(x[1])]])


def _projector(B, P):
    return B @ np.linalg.solve(B.T @ P @ B, B.T @ P)


def _sigma_M(T):
    rho = np.abs(np.linalg.eigvals(T)).max()
    sigma = 0.5 * (1.0 + rho)
    Tk, best, k = np.eye(T.shape[0]), 1.0, 0
    while True:
        Tk, k = T @ Tk, k + 1
        ratio = np.linalg.norm(Tk, 2) / sigma**k
        best = max(best, ratio)
        if ratio < 1e-3 * best and k > 10:
            return sigma, best


# ---- Prop. 2.3.1 -----------------------------------------------------------------------------------------------


def _check_projection(P, f, g, rng):
    """x+ = f + g u with u from (2.9) equals the P-norm projection of f onto {y : g^T P y = 0}, found as the
    least-squares point of the null space of g^T P (SciPy) in the Cholesky metric."""
    u = np.asarray(projection(jnp.asarray(P), jnp.asarray(f), jnp.asarray(g))).reshape(-1)
    xp = f + g @ u
    N = sla.null_space(g.T @ P)
    S = sla.cholesky(P)  # ||z||_P = ||S z||
    ref = N @ np.linalg.lstsq(S @ N, S @ f, rcond=None)[0]
    scale = np.linalg.norm(S @ f)
    assert np.linalg.norm(S @ (xp - ref)) <= 1e-9 * scale
    for y in (N @ rng.normal(size=(N.shape[1], 20))).T:  # no point of the subspace is closer to f
        assert np.linalg.norm(S @ (y - f)) >= np.linalg.norm(S @ (xp - f)) * (1 - 1e-12)


def test_prop_2_3_1_projection():
    """Prop. 2.3.1 on the nonlinear example (50 random states; f, g written in NumPy) and the DIP (f = Phi x,
    g = W; P with singular values 1e9 and 1)."""
    rng = np.random.default_rng(0)
    P = np.asarray(P_v(jnp.array([0.9950, 0.1003]), 1e6))
    for x in rng.normal(size=(50, 2)) * 2:
        _check_projection(P, *_nonlinear_fg(x), rng)
    Phi, W, Pd = _dip_example()
    for x in rng.normal(size=(20, 6)) * 0.1:
        _check_projection(Pd, Phi @ x, W, rng)


# ---- Prop. 2.3.3 -----------------------------------------------------------------------------------------------


def _def_2_3_2_alpha(T, P):
    """Definition 2.3.2 for a linear closed loop: ||T x||_P^2 - ||x||_P^2 <= -alpha ||x||_P^2 for all x with
    alpha = 1 - (largest generalised eigenvalue of (T^T P T, P))."""
    return 1.0 - sla.eigh(T.T @ P @ T, P, eigvals_only=True).max()


def test_prop_2_3_3_linear_example():
    """On §2.7.1: alpha of Definition 2.3.2 is 0.78 (P is globally exponentially stabilising for (2.9)); for every
    gamma above (1 - sqrt(alpha))/sqrt(alpha) the relaxed closed loop T + c Q satisfies the proposition's
    ||x+||_P^2 - ||x||_P^2 <= -(alpha - c^2) ||x||_P^2 for all x (generalised eigenvalues), and jaxdip's (2.10)
    gives that closed loop. At gamma = 0 (c = 1) the state z in R(B) gets ||x+||_P >= ||x||_P: no decrease,
    so the weight condition is not idle."""
    A, B, P = _linear_example()
    Q = _projector(B, P)
    T = np.asarray(projected_closed_loop(jnp.asarray(A), jnp.asarray(B), jnp.asarray(P)))
    np.testing.assert_allclose(T, (np.eye(2) - Q) @ A, atol=1e-12)
    alpha = _def_2_3_2_alpha(T, P)
    assert 0.7 < alpha < 0.85
    g_min = (1 - np.sqrt(alpha)) / np.sqrt(alpha)
    rng = np.random.default_rng(1)
    for gamma in (1.001 * g_min, 2 * g_min, 10 * g_min, 1e3):
        c = 1 / (1 + gamma)
        Mc = T + c * Q
        x = rng.normal(size=2)
        u = np.asarray(relaxed_discrete(jnp.asarray(P), jnp.asarray(A @ x), jnp.asarray(B), jnp.asarray(x), gamma))
        np.testing.assert_allclose(A @ x + B @ u, Mc @ x, atol=1e-10)
        zeta = alpha - c**2
        assert 0 < zeta < 1
        assert sla.eigh(Mc.T @ P @ Mc, P, eigvals_only=True).max() <= 1 - zeta + 1e-10
    M0 = T + Q
    assert sla.eigh(M0.T @ P @ M0, P, eigvals_only=True).max() >= 1.0


def test_prop_2_3_3_nonlinear_example():
    """On §2.7.2 over the square [-2, 2]^2: alpha of Definition 2.3.2 measured on a grid under (2.9) (0 < alpha
    < 1), then every grid state whose (2.18) weight 0.1/||x||^2 exceeds (1 - sqrt(alpha))/sqrt(alpha) has
    ||x+||_P^2 - ||x||_P^2 <= -(alpha - c^2) ||x||_P^2 under (2.10), f and g in NumPy."""
    P = np.asarray(P_v(jnp.array([0.9950, 0.1003]), 1e6))
    grid = np.stack(np.meshgrid(np.linspace(-2, 2, 41), np.linspace(-2, 2, 41)), -1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid, axis=1) > 1e-3]
    pn = lambda z: float(z @ P @ z)  # noqa: E731
    ratios = []
    for x in grid:
        f, g = _nonlinear_fg(x)
        ratios.append(pn(f + g @ np.asarray(projection(P, f, g))) / pn(x))
    alpha = 1.0 - max(ratios)
    assert 0 < alpha < 1
    g_min = (1 - np.sqrt(alpha)) / np.sqrt(alpha)
    checked = 0
    for x in grid:
        gamma = float(state_weight(0.1, 2.0, x))
        if gamma <= g_min:
            continue
        f, g = _nonlinear_fg(x)
        xn = f + g @ np.asarray(relaxed_discrete(P, f, g, x, gamma))
        assert pn(xn) - pn(x) <= -(alpha - 1 / (1 + gamma) ** 2) * pn(x) * (1 - 1e-9)
        checked += 1
    assert checked > 100


def test_prop_2_3_3_hypothesis_fails_on_the_dip_p():
    """The DIP's P stabilises projection control in the sense of Definition 2.5.1 (spectral radius 0.999) but
    not in that of Definition 2.3.2 (one step can grow ||x||_P: alpha < 0), so Prop. 2.3.3 gives nothing there
    and the DIP's relaxed weights rest on Props 2.5.4-2.5.5 instead."""
    Phi, W, P = _dip_example()
    T = (np.eye(6) - _projector(W, P)) @ Phi
    assert np.abs(np.linalg.eigvals(T)).max() < 1
    assert _def_2_3_2_alpha(T, P) < 0


# ---- Props 2.5.2-2.5.5 -----------------------------------------------------------------------------------------


def _simulate_216(A, B, P, x0, gammas):
    """(2.16) step by step in NumPy."""
    Q = _projector(B, P)
    T = (np.eye(A.shape[0]) - Q) @ A
    xs, x = [], x0
    for g in gammas:
        x = T @ x + Q @ x / (1 + g)
        xs.append(x)
    return np.array(xs)


def test_prop_2_5_2_closed_form():
    """(2.17) derived again (module docstring) equals (2.16) simulated, on both systems with random weights; the
    printed (2.17) (T^k v_0 in place of T^k x_0) misses by T^k z_0, far above rounding."""
    rng = np.random.default_rng(2)
    for name, make in SYSTEMS.items():
        A, B, P = make()
        d = A.shape[0]
        Q = _projector(B, P)
        T = (np.eye(d) - Q) @ A
        x0 = rng.normal(size=d)
        gammas = 10 ** rng.uniform(-2, 2, size=25)
        sim = _simulate_216(A, B, P, x0, gammas)
        closed = np.asarray(relaxed_closed_form(A, B, P, x0, gammas))
        np.testing.assert_allclose(closed, sim, atol=1e-10 * np.abs(sim).max())
        z0 = Q @ x0
        printed = closed - np.stack([np.linalg.matrix_power(T, k) @ z0 for k in range(1, 26)])
        assert np.abs(printed - sim).max() > 1e-3 * np.abs(sim).max(), name


def test_prop_2_5_3_bounded():
    """Any positive weights (log-uniform over 1e-3..1e3, 30 trajectories per system): ||x_k|| stays below
    M (||x_0|| + ||z_0||/(1 - sigma)) at every k."""
    rng = np.random.default_rng(3)
    printed_held = True
    for name, make in SYSTEMS.items():
        A, B, P = make()
        d = A.shape[0]
        Q = _projector(B, P)
        T = (np.eye(d) - Q) @ A
        sigma, M = _sigma_M(T)
        for _ in range(30):
            x0 = rng.normal(size=d)
            z0 = Q @ x0
            xs = _simulate_216(A, B, P, x0, 10 ** rng.uniform(-3, 3, size=400))
            n = np.linalg.norm(xs, axis=1)
            assert n.max() <= M * (np.linalg.norm(x0) + np.linalg.norm(z0) / (1 - sigma)), name
            printed_held &= bool((n**2).max() <= M * (np.linalg.norm(x0 - z0) ** 2
                                                       + np.linalg.norm(z0) ** 2 / (1 - sigma)))
    print(f"\nProp 2.5.3: the printed squared form held on these trajectories: {printed_held}")


def test_prop_2_5_4_exponential():
    """Weights with c_k < eta = 0.9 (random, per step): ||x_k|| <= M sigma^k ||x_0|| + M ||z_0|| k r^k at every
    k, r = max(sigma, eta), and the state decays. Without the hypothesis (gamma_k = 1/(k+1)^2, so c_k -> 1 and
    the product of the c_k tends to pi/sinh(pi) = 0.272) Q x_k stays near 0.272 Q x_0: no convergence."""
    rng = np.random.default_rng(4)
    eta = 0.9
    for name, make in SYSTEMS.items():
        A, B, P = make()
        d = A.shape[0]
        Q = _projector(B, P)
        T = (np.eye(d) - Q) @ A
        sigma, M = _sigma_M(T)
        r = max(sigma, eta)
        K = 400 if d == 2 else 40000
        k = np.arange(1, K + 1)
        for _ in range(3):
            x0 = rng.normal(size=d)
            z0 = Q @ x0
            c = rng.uniform(0.0, eta, size=K)
            xs = _simulate_216(A, B, P, x0, 1 / c - 1)
            bound = M * sigma**k * np.linalg.norm(x0) + M * np.linalg.norm(z0) * k * r**k
            assert np.all(np.linalg.norm(xs, axis=1) <= bound), name
            assert np.linalg.norm(xs[-1]) < 1e-6 * np.linalg.norm(x0), name
        x0 = rng.normal(size=d)
        xs = _simulate_216(A, B, P, x0, 1.0 / (np.arange(K) + 1.0) ** 2)
        np.testing.assert_allclose(Q @ xs[-1], np.pi / np.sinh(np.pi) * (Q @ x0), rtol=1e-2)


def test_prop_2_5_5_state_weights():
    """The weights (2.18) gamma_k = gamma/||x_k||^alpha: the thesis's gamma = 0.45, alpha = 3 from x_0 = [2, 1]
    on §2.7.1, and gamma = 1, alpha = 2 from a 0.1-sized state on the DIP, run through jaxdip's (2.10) and
    state_weight. The proof's route holds step by step: c_k <= eta = B^alpha/(gamma + B^alpha) with B the
    bound of Prop. 2.5.3 (so Prop. 2.5.4 applies), the state obeys Prop. 2.5.4's bound, and it decays."""
    cases = {"linear 2.7.1": (0.45, 3.0, np.array([2.0, 1.0]), 400),
             "DIP 1 ms": (1.0, 2.0, 0.1 * np.array([1.0, 0.5, -0.5, 0.0, 1.0, -1.0]), 40000)}
    for name, make in SYSTEMS.items():
        gamma, alpha, x0, K = cases[name]
        A, B, P = make()
        Q = _projector(B, P)
        T = (np.eye(A.shape[0]) - Q) @ A
        sigma, M = _sigma_M(T)
        z0 = Q @ x0
        bnd = M * (np.linalg.norm(x0) + np.linalg.norm(z0) / (1 - sigma))
        eta = bnd**alpha / (gamma + bnd**alpha)
        r = max(sigma, eta)
        x, cs, ns = x0, [], []
        for k in range(K):
            if k < 5:  # jaxdip's law and weight at the first steps
                u = np.asarray(relaxed_discrete(jnp.asarray(P), jnp.asarray(A @ x), jnp.asarray(B), jnp.asarray(x),
                                                state_weight(gamma, alpha, jnp.asarray(x))))
                x_j = A @ x + B @ u
            g = gamma / np.linalg.norm(x) ** alpha
            cs.append(1 / (1 + g))
            x = T @ x + Q @ x / (1 + g)
            if k < 5:
                np.testing.assert_allclose(x_j, x, atol=1e-9 * np.linalg.norm(x0))
            ns.append(np.linalg.norm(x))
            if ns[-1] < 1e-12 * np.linalg.norm(x0):
                break
        k = np.arange(1, len(ns) + 1)
        assert max(cs) <= eta, name
        assert np.all(np.array(ns) <= M * sigma**k * np.linalg.norm(x0) + M * np.linalg.norm(z0) * k * r**k), name
        assert ns[-1] < 1e-6 * np.linalg.norm(x0), name
