"""LS proximal MHE, CPX and SCPX against NumPy/SciPy references written here (lstsq, expm, eigh)."""

import jaxdip  # noqa: F401  (float64)

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla

from jaxdip.estimators import cpx as cpxmod
from jaxdip.engine.roles import Plant, param
from jaxdip.estimators.cpx import CPX, LinearizedCPX
from jaxdip.estimators.linearized import local_model
from jaxdip.estimators.proximal import (LeastSquaresMHE, horizon_stack, ls_mhe_filter, prox_ls,
                                        prox_ls_svd)
from jaxdip.estimators.recorded import run
from jaxdip.estimators.wrappers import Ahead
from jaxdip.plants import dip, lorenz
from jaxdip.engine.integrate import rk4_zoh
from jaxdip.engine.roles import linearize
from jaxdip.sim import Discrete

GAMMAS = [1e-3, 0.5, 50.0, 150.0, 2.44e4, 1e5]


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300)


def brute_prox(G, q, xhat, gamma):
    """argmin 1/2||Gz - q||^2 + 1/(2 gamma)||z - xhat||^2 by NumPy's SVD-based lstsq of the stacked system."""
    d = G.shape[1]
    H = np.vstack([G, np.eye(d) / np.sqrt(gamma)])
    r = np.concatenate([q, xhat / np.sqrt(gamma)])
    return np.linalg.lstsq(H, r, rcond=None)[0]


def _dip_G():
    A, _ = linearize(dip.DIP(), jnp.zeros(6), 0.0)
    A = np.asarray(A)
    C = np.eye(6)[:3]
    return np.vstack([C @ sla.expm(-A * 1e-3), C, C @ sla.expm(A * 1e-3)])


def _ill_G(rng):
    U, _ = np.linalg.qr(rng.standard_normal((9, 6)))
    V, _ = np.linalg.qr(rng.standard_normal((6, 6)))
    return U @ np.diag(np.logspace(0, -6, 6)) @ V.T


@pytest.fixture(scope="module")
def matrices():
    rng = np.random.default_rng(7)
    return {"random": rng.standard_normal((6, 3)), "ill-cond 1e-6": _ill_G(rng), "dip-cpx-1ms": _dip_G()}


@pytest.mark.parametrize("name", ["random", "ill-cond 1e-6", "dip-cpx-1ms"])
def test_prox_equals_bruteforce(matrices, name):
    G = matrices[name]
    rng = np.random.default_rng(1)
    q = rng.standard_normal(G.shape[0])
    xhat = 3 * rng.standard_normal(G.shape[1])
    f_qr = jax.jit(prox_ls)
    f_svd = jax.jit(prox_ls_svd)
    worst = 0.0
    for g in GAMMAS:
        ref = brute_prox(G, q, xhat, g)
        for f in (f_qr, f_svd):
            p = np.asarray(f(jnp.asarray(G), jnp.asarray(q), jnp.asarray(xhat), g))
            worst = max(worst, rel(p, ref))
            # first-order optimality, independent of any solver
            grad = G.T @ (G @ p - q) + (p - xhat) / g
            scale = np.linalg.norm(G.T @ q) + np.linalg.norm(xhat) / g + np.linalg.norm(G.T @ G @ p)
            assert np.linalg.norm(grad) <= 1e-11 * scale
    print(f"\n{name}: max relative difference to numpy lstsq over gamma in {GAMMAS}: {worst:.2e}")
    assert worst < 1e-10


def _np_horizon(Phis, Ws, us, Cs, ys):
    """G, q by explicit products, written independently of horizon_stack."""
    N, d = Phis.shape[0], Phis.shape[1]
    rows, qs = [], []
    for i in range(1, N + 1):
        M = np.eye(d)
        for j in range(i):
            M = Phis[j] @ M
        s = np.zeros(d)
        for j in range(i):  # response to u_{k+j} through Phi_{k+i-1} .. Phi_{k+j+1}
            P = np.eye(d)
            for l in range(j + 1, i):
                P = Phis[l] @ P
            s += P @ Ws[j] @ us[j]
        rows.append(Cs[i - 1] @ M)
        qs.append(ys[i - 1] - Cs[i - 1] @ s)
    return np.vstack(rows), np.concatenate(qs)


def test_horizon_stack_ltv():
    rng = np.random.default_rng(3)
    N, d, m, p = 4, 3, 2, 2
    Phis = rng.standard_normal((N, d, d))
    Ws, us = rng.standard_normal((N, d, m)), rng.standard_normal((N, m))
    Cs, ys = rng.standard_normal((N, p, d)), rng.standard_normal((N, p))
    G, q = horizon_stack(*map(jnp.asarray, (Phis, Ws, us, Cs, ys)))
    Gr, qr = _np_horizon(Phis, Ws, us, Cs, ys)
    assert rel(G, Gr) < 1e-13 and rel(q, qr) < 1e-13


# ---- a random LTI system with inputs and noise --------------------------------------------------------


def _lti(rng, d=4, m=1, p=2, h=0.05):
    A = rng.standard_normal((d, d))
    A -= (np.linalg.eigvals(A).real.max() - 0.3) * np.eye(d)  # mildly unstable: the estimator has work to do
    B = rng.standard_normal((d, m))
    C = rng.standard_normal((p, d))
    M = np.zeros((d + m, d + m))
    M[:d, :d], M[:d, d:] = A, B
    E = sla.expm(M * h)
    return A, B, C, E[:d, :d], sla.expm(-A * h), E[:d, d:]


def _simulate(rng, Phi, W, C, T, eta=0.05, eps=0.1):
    d, m = W.shape
    x = rng.standard_normal(d)
    xs, ys, us = [], [], []
    for _ in range(T):
        xs.append(x)
        ys.append(C @ x + eps * rng.standard_normal(C.shape[0]))
        u = np.sin(0.3 * len(us)) * np.ones(m) + 0.1 * rng.standard_normal(m)
        us.append(u)
        x = Phi @ x + W @ u + eta * rng.standard_normal(d)
    us = np.array(us)
    us_prev = np.vstack([np.zeros((1, m)), us[:-1]])
    return np.array(xs), np.array(ys), us, us_prev


def np_cpx(Phi, Phi_inv, W, C, gamma, ys, us_prev, xhat0, keep=None):
    """Reference CPX/SCPX: explicit G, q, NumPy lstsq (or an eigh-built projector for SCPX), plain loop."""
    xc = np.array(xhat0, float)
    outs, cur = [], []
    G = np.vstack([C @ Phi_inv, C, C @ Phi])
    for j in range(len(ys)):
        u = us_prev[j]
        if j == 0:
            xhat = xc
        else:
            if j >= 2:
                q = np.concatenate([ys[j - 2] + C @ Phi_inv @ W @ us_prev[j - 1], ys[j - 1], ys[j] - C @ W @ u])
                if keep is None:
                    p = brute_prox(G, q, xc, gamma)
                else:
                    p = brute_scpx(G, q, xc, gamma, keep)
            else:
                p = xc
            xhat = Phi @ p + W @ u
        cur.append(xhat)
        outs.append(Phi @ xhat + W @ u)
        xc = xhat
    return np.array(outs), np.array(cur)


def brute_scpx(G, q, xhat, gamma, keep):
    """Minimise 1/2 (Gz - q)^T P (Gz - q) + 1/(2 gamma)||z - xhat||^2 with P built as in thesis §1.5 from eigh."""
    lam, U = np.linalg.eigh(G.T @ G)
    order = np.argsort(lam)[::-1]
    lam, U = lam[order], U[:, order]
    # P = [G U, V] diag(Sigma, 0) [G U, V]^T with Sigma_ii = lambda_i / lambda_i^2 for the kept i
    GU = G @ U[:, :keep]
    P = GU @ np.diag(lam[:keep] / lam[:keep] ** 2) @ GU.T
    w, V = np.linalg.eigh(P)  # P is PSD and singular: fit with its symmetric square root S, S^T S = P
    S = V @ np.diag(np.sqrt(np.clip(w, 0, None))) @ V.T
    return brute_prox(S @ G, S @ q, xhat, gamma)


@pytest.fixture(scope="module")
def lti_data():
    rng = np.random.default_rng(11)
    A, B, C, Phi, Phi_inv, W = _lti(rng)
    xs, ys, us, us_prev = _simulate(rng, Phi, W, C, 300)
    return dict(A=A, B=B, C=C, Phi=Phi, Phi_inv=Phi_inv, W=W, xs=xs, ys=ys, us=us, us_prev=us_prev)


class LinearPlant(Plant):
    """xdot = A x + B u: a linear plant for the linearised forms."""

    A: jax.Array = param()
    B: jax.Array = param()
    state_names = ("x1", "x2", "x3", "x4")

    def vector_field(self, x, u):
        return self.A @ x + self.B @ u


# one compiled run per estimator structure: gamma, the model and the data are arguments
_outputs = jax.jit(lambda est, ys, us_prev: run(est, ys, us_prev, jnp.zeros(4))[1])


def _run(est, D):
    return np.asarray(_outputs(est, D["ys"], D["us_prev"]))


def _cpx(gamma, D, x0, keep=None, ahead=True):
    """CPX on the LTI model (SCPX with ``keep``), handing out its prediction unless ``ahead=False``."""
    e = CPX(gamma, Discrete(*map(jnp.asarray, (D["Phi"], D["Phi_inv"], D["W"]))), jnp.asarray(D["C"]),
            jnp.asarray(x0), keep=keep)
    return Ahead(e) if ahead else e


def _lin(gamma, D, x0, keep=None):
    return Ahead(LinearizedCPX(gamma, LinearPlant(D["A"], D["B"]), jnp.asarray(D["C"]), jnp.asarray(x0), h=0.05,
                               keep=keep))


@pytest.mark.parametrize("gamma", [50.0, 150.0, 1e5])
def test_cpx_qr_matches_numpy(lti_data, gamma):
    D = lti_data
    x0 = np.array([1.0, -2.0, 0.5, 0.0])
    out = _run(_cpx(gamma, D, x0), D)
    ref, ref_cur = np_cpx(D["Phi"], D["Phi_inv"], D["W"], D["C"], gamma, D["ys"], D["us_prev"], x0)
    assert rel(out, ref) < 1e-10
    cur = _run(_cpx(gamma, D, x0, ahead=False), D)
    assert rel(cur, ref_cur) < 1e-10
    # the estimate does track the state (a test that a wrong sign in the input terms would fail)
    err = np.linalg.norm(cur[50:] - D["xs"][50:], axis=1).mean()
    assert err < 0.5 * np.linalg.norm(D["xs"][50:], axis=1).mean()


def test_cpx_linearized_equals_qr_on_linear_plant(lti_data):
    """The linearised SVD form on a linear plant must reproduce the offline-QR form (same minimiser)."""
    D = lti_data
    x0 = jnp.array([1.0, -2.0, 0.5, 0.0])
    for gamma in (50.0, 1e4):
        lin = _run(_lin(gamma, D, x0), D)
        qr = _run(_cpx(gamma, D, x0), D)
        assert rel(lin, qr) < 1e-9


@pytest.mark.parametrize("keep", [1, 2, 4])
def test_scpx_matches_projector_bruteforce(lti_data, keep):
    D = lti_data
    x0 = np.array([0.5, 0.5, -1.0, 2.0])
    gamma = 50.0
    out = _run(_cpx(gamma, D, x0, keep=keep), D)
    ref, _ = np_cpx(D["Phi"], D["Phi_inv"], D["W"], D["C"], gamma, D["ys"], D["us_prev"], x0, keep=keep)
    assert rel(out, ref) < 1e-9
    lin = _run(_lin(gamma, D, x0, keep=keep), D)
    assert rel(lin, ref) < 1e-9
    if keep == 4:  # all directions kept: SCPX is CPX
        full = _run(_cpx(gamma, D, x0), D)
        assert rel(out, full) < 1e-10


def test_ls_mhe_filter_and_component(lti_data):
    """Sequence form (LTV code path with constant matrices) vs the online estimator, QR vs SVD, horizon 1..4."""
    D = lti_data
    T = 120
    Phi, W, C = (jnp.asarray(D[k]) for k in ("Phi", "W", "C"))
    Phis = jnp.broadcast_to(Phi, (T,) + Phi.shape)
    Ws = jnp.broadcast_to(W, (T,) + W.shape)
    Cs = jnp.broadcast_to(C, (T + 1,) + C.shape)
    ys = jnp.asarray(D["ys"][: T + 1])
    us = jnp.asarray(D["us"][:T])
    x0 = jnp.array([1.0, 0.0, -1.0, 0.5])
    for N in (1, 3):
        tr_qr = ls_mhe_filter(2.0, Phis, Ws, us, Cs, ys, x0, N=N)
        tr_svd = ls_mhe_filter(2.0, Phis, Ws, us, Cs, ys, x0, N=N, method="svd")
        assert rel(tr_qr.xhat, tr_svd.xhat) < 1e-10
        # the online estimator at sample j >= N outputs the current estimate xhat_j: the window starting at
        # x_{j-N} gives xhat_{j-N+1}, propagated N - 1 steps with the known inputs
        est = LeastSquaresMHE(2.0, Phi, W, C, x0, N=N)
        _, out, _ = run(est, ys, jnp.asarray(D["us_prev"][: T + 1]), x0)
        out = np.asarray(out)
        xh = np.asarray(tr_qr.xhat)
        for j in range(N, T + 1):
            x = xh[j - N + 1]
            for i in range(j - N + 1, j):
                x = np.asarray(Phi) @ x + np.asarray(W) @ np.asarray(us[i])
            assert rel(out[j], x) < 1e-10, (N, j)


def test_local_model_linear_and_lorenz():
    rng = np.random.default_rng(5)
    A, B = rng.standard_normal((3, 3)), rng.standard_normal((3, 1))
    f = lambda prm, x, u: A @ x + B @ u  # noqa: E731
    xbar, ubar, h = rng.standard_normal(3), np.array([0.7]), 0.1
    lm = jax.jit(local_model, static_argnums=(0, 4))(f, None, jnp.asarray(xbar), jnp.asarray(ubar), h)
    M = np.zeros((4, 4))
    M[:3, :3], M[:3, 3:] = A, B
    E = sla.expm(M * h)
    assert rel(lm.Phi, E[:3, :3]) < 1e-13 and rel(lm.W, E[:3, 3:]) < 1e-13
    assert np.abs(np.asarray(lm.b)).max() < 1e-13  # linear dynamics: no offset
    assert rel(lm.Phi_inv, sla.expm(-A * h)) < 1e-13
    # Lorenz: the local affine step is the exponential-Euler step, close to the true flow at h = 1e-3
    p = lorenz.Lorenz()
    x = jnp.array([-5.0, -8.0, 20.0])
    lm = jax.jit(local_model, static_argnums=(0, 4))(lorenz.f, p, x, jnp.zeros(1), 1e-3)
    flow = jax.jit(lambda g, z: rk4_zoh(g, p, z, jnp.zeros(1), 1e-3, 20), static_argnums=0)
    ref = flow(lorenz.f, x)
    assert np.abs(np.asarray(lm.Phi @ x + lm.b - ref)).max() < 1e-5
    back = lm.Phi_inv @ (x - lm.b)
    ref_b = flow(lambda prm, z, u: -lorenz.f(prm, z, u), x)
    assert np.abs(np.asarray(back - ref_b)).max() < 1e-5


def test_cpx_gradient_wrt_gamma(lti_data):
    D = lti_data
    base = _cpx(1.0, D, np.zeros(4), ahead=False)
    xs = jnp.asarray(D["xs"])

    def loss(g):
        _, out, _ = run(eqx.tree_at(lambda e: e.gamma, base, g), D["ys"], D["us_prev"], jnp.zeros(4))
        return jnp.mean(jnp.linalg.norm(out - xs, axis=1))

    g0, dg = 60.0, 1e-3
    ad = jax.grad(loss)(g0)
    fd = (loss(g0 + dg) - loss(g0 - dg)) / (2 * dg)
    assert abs(ad - fd) <= 1e-6 * abs(fd)


def test_centered_vector_backward_term():
    """C z_{k-1} = C Phi^{-1} z_k - C Phi^{-1} W u_{k-1}: q's first block against a simulated step."""
    rng = np.random.default_rng(2)
    _, _, C, Phi, Phi_inv, W = _lti(rng)
    x_prev, u_back, u_fwd = rng.standard_normal(4), rng.standard_normal(1), rng.standard_normal(1)
    x = Phi @ x_prev + W @ u_back
    x_next = Phi @ x + W @ u_fwd
    step = cpxmod.lti_step(*map(jnp.asarray, (Phi, Phi_inv, W)))
    G = cpxmod.centered_matrix(step, jnp.asarray(C))
    q = cpxmod.centered_vector(step, jnp.asarray(C), C @ x_prev, C @ x, C @ x_next, jnp.asarray(u_back),
                               jnp.asarray(u_fwd))
    assert rel(G @ x, q) < 1e-12  # noise-free data: the true centre state fits exactly


def test_jacobi_svd_matches_lapack():
    from jaxdip.estimators.proximal import jacobi_svd

    rng = np.random.default_rng(9)
    cases = [rng.standard_normal((6, 3)), _ill_G(rng), _dip_G(), rng.standard_normal((2, 4)),
             np.outer(rng.standard_normal(6), rng.standard_normal(3))]  # random, cond 1e6, DIP, l < d, rank 1
    f = jax.jit(jacobi_svd)
    prox = jax.jit(lambda G, q, xh, g: prox_ls_svd(G, q, xh, g, method="jacobi"))
    for G in cases:
        Ug, s, V = map(np.asarray, f(jnp.asarray(G)))
        s_ref = np.linalg.svd(G, compute_uv=False)
        k = len(s_ref)
        assert np.abs(s[:k] - s_ref).max() <= 1e-14 * s_ref[0]
        assert np.abs(s[k:]).max(initial=0.0) <= 1e-14 * s_ref[0]
        assert np.abs(V.T @ V - np.eye(G.shape[1])).max() < 1e-14
        assert np.abs(G @ V - Ug * s).max() <= 1e-14 * s_ref[0]
        if G.shape == (6, 3):  # the proximal step through it equals brute force (one compile: the Lorenz shape)
            q, xh = rng.standard_normal(G.shape[0]), rng.standard_normal(G.shape[1])
            for g in (0.5, 1e5):
                p = prox(jnp.asarray(G), jnp.asarray(q), jnp.asarray(xh), g)
                assert rel(p, brute_prox(G, q, xh, g)) < 1e-10


def test_expm_small_matches_scipy():
    from jaxdip.estimators.linearized import expm_small

    rng = np.random.default_rng(10)
    f = jax.jit(expm_small)
    for scale in (1e-4, 0.03, 1.0, 30.0, 1e3):
        for n in (3, 5):
            A = rng.standard_normal((n, n)) * scale / np.sqrt(n)
            ref = sla.expm(A)
            # relative to the exponential's size; squaring-phase rounding grows with ||A||, as for any expm
            assert np.abs(np.asarray(f(jnp.asarray(A))) - ref).max() <= 1e-13 * max(1.0, scale) * np.abs(ref).max()
