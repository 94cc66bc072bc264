"""Props 1.4.2, 1.4.3, 1.5.1 against simulated estimators; the DIP criterion of thesis §3.3."""

import jaxdip  # noqa: F401  (float64)

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla

from jaxdip.estimators.cpx import CPX, centered_matrix
from jaxdip.estimators.linearized import lti_step
from jaxdip.estimators.proximal import horizon_stack, ls_mhe_filter
from jaxdip.estimators.recorded import run
from jaxdip.plants import dip
from jaxdip.engine.roles import linearize
from jaxdip.sim import Discrete
from jaxdip.theory import mhe


def _expm_pair(A, B, h):
    d, m = B.shape
    M = np.zeros((d + m, d + m))
    M[:d, :d], M[:d, d:] = A, B
    E = sla.expm(M * h)
    return E[:d, :d], sla.expm(-A * h), E[:d, d:]


def test_prop_1_4_2_ltv_horizon():
    """LTV model with inputs, horizon N = 3, varying gamma_k: the recursion reproduces xhat_k - x_k."""
    rng = np.random.default_rng(42)
    d, m, p, N, T, h = 4, 1, 2, 3, 150, 0.05
    A0 = rng.standard_normal((d, d))
    A0 -= (np.linalg.eigvals(A0).real.max() - 0.5) * np.eye(d)
    D = rng.standard_normal((d, d))
    B = rng.standard_normal((d, m))
    Phis, Ws, Cs = [], [], []
    for k in range(T):
        Phi, _, W = _expm_pair(A0 + 0.5 * np.sin(0.1 * k) * D, B, h)
        Phis.append(Phi)
        Ws.append(W)
    C0 = rng.standard_normal((p, d))
    Cs = np.array([C0 + 0.2 * np.cos(0.2 * k) * np.eye(p, d) for k in range(T + 1)])
    Phis, Ws = np.array(Phis), np.array(Ws)
    us = rng.standard_normal((T, m))
    etas = 0.05 * rng.standard_normal((T, d))
    epss = 0.2 * rng.standard_normal((T + 1, p))
    xs = [rng.standard_normal(d)]
    for k in range(T):
        xs.append(Phis[k] @ xs[-1] + Ws[k] @ us[k] + etas[k])
    xs = np.array(xs)
    ys = np.einsum("kpd,kd->kp", Cs, xs) + epss
    K = T - N + 1
    gammas = 5.0 + 3.0 * np.sin(np.arange(K))
    xhat0 = xs[0] + rng.standard_normal(d)
    tr = ls_mhe_filter(jnp.asarray(gammas), *map(jnp.asarray, (Phis, Ws, us, Cs, ys, xhat0)), N=N)

    Pj, Wj, uj, Cj, yj, ej, sj = map(jnp.asarray, (Phis, Ws, us, Cs, ys, etas, epss))

    @jax.jit
    @jax.vmap
    def window(k):
        def sl(a, start):
            return jax.lax.dynamic_slice_in_dim(a, start, N, axis=0)

        G, q = horizon_stack(sl(Pj, k), sl(Wj, k), sl(uj, k), sl(Cj, k + 1), sl(yj, k + 1))
        v = mhe.horizon_noise(sl(Pj, k), sl(Cj, k + 1), sl(ej, k), sl(sj, k + 1))
        return G, q, v, mhe.discrepancy(G, v)

    Gs, qs, vs, zetas = window(jnp.arange(K))
    # the thesis's v_k is the window's noise: q_k = G_k x_k + v_k
    assert np.abs(np.asarray(qs) - np.einsum("kld,kd->kl", np.asarray(Gs), xs[:K]) - np.asarray(vs)).max() < 1e-12
    e_rec = mhe.error_recursion(jnp.asarray(Phis[:K]), Gs, jnp.asarray(gammas), xhat0 - xs[0], zetas,
                                jnp.asarray(etas[:K]))
    e_sim = np.asarray(tr.xhat) - xs[: K + 1]
    err = np.abs(np.asarray(e_rec) - e_sim).max()
    print(f"\nProp 1.4.2 (LTV, N={N}): max |e_recursion - e_simulated| = {err:.1e} (max |e| {np.abs(e_sim).max():.2f})")
    assert err < 1e-10


def _lti_system(key, d=3, p=2, h=0.1):
    k1, k2, k3 = jax.random.split(key, 3)
    A = jax.random.normal(k1, (d, d))
    A = A - (jnp.max(jnp.linalg.eigvals(A).real) - 0.3) * jnp.eye(d)  # max Re(lambda) = 0.3: unstable
    B = jax.random.normal(k2, (d, 1))
    C = jax.random.normal(k3, (p, d))
    M = jnp.zeros((d + 1, d + 1)).at[:d, :d].set(A).at[:d, d:].set(B)
    E = jax.scipy.linalg.expm(M * h)
    return Discrete(E[:d, :d], jax.scipy.linalg.expm(-A * h), E[:d, d:]), C


def _ball(key, shape, radius):
    """Uniform in the ball of ``radius`` (last axis): bounded noise, as Prop 1.4.3 assumes (A2)."""
    k1, k2 = jax.random.split(key)
    g = jax.random.normal(k1, shape)
    g = g / jnp.linalg.norm(g, axis=-1, keepdims=True)
    return g * radius * jax.random.uniform(k2, shape[:-1] + (1,)) ** (1.0 / shape[-1])


def _cpx_trial(key, T=200, keep=None):
    """Simulate a random LTI system with bounded noise and run CPX (or SCPX); return what the props need."""
    ks = jax.random.split(key, 8)
    model, C = _lti_system(ks[0])
    d, p = model.Phi.shape[0], C.shape[0]
    G = centered_matrix(lti_step(*model), C)
    crit, K, lam_min = mhe.lti_gamma_criterion(model.Phi, G)
    gamma = crit * (1.0 + jax.random.uniform(ks[1], minval=0.05, maxval=3.0)) + 1e-3
    eta_bar, eps_bar = 0.05, 0.2
    etas = _ball(ks[2], (T, d), eta_bar)
    epss = _ball(ks[3], (T, p), eps_bar)
    us = jnp.sin(0.3 * jnp.arange(T))[:, None] + 0.1 * jax.random.normal(ks[4], (T, 1))
    x0 = jax.random.normal(ks[5], (d,))

    def sim(x, inp):
        u, eta = inp
        return model.Phi @ x + model.W @ u + eta, x

    _, xs = jax.lax.scan(sim, x0, (us, etas))
    ys = xs @ C.T + epss
    us_prev = jnp.concatenate([jnp.zeros((1, 1)), us[:-1]])
    xhat0 = x0 + 2.0 * jax.random.normal(ks[6], (d,))
    _, xh, _ = run(CPX(gamma, model, C, xhat0, keep=keep), ys, us_prev, x0)
    # centres k = 1 .. T-2 (sample j = k + 1 holds the prior of centre k); zeta_k from (1.30)
    k = jnp.arange(1, T - 1)
    v = jax.vmap(lambda i: mhe.centered_noise(model.Phi_inv, C, etas[i - 1], epss[i - 1], epss[i], etas[i],
                                              epss[i + 1]))(k)
    zetas = jax.vmap(lambda vi: mhe.discrepancy(G, vi))(v)
    e = xh[k] - xs[k]  # xh[k] is xhat_k: the prior of centre k
    return dict(e=e, zetas=zetas, etas=etas[k], G=G, Phi=model.Phi, gamma=gamma, K=K, lam_min=lam_min,
                crit=crit)


def test_prop_1_4_2_cpx_and_1_5_1_scpx():
    for keep in (None, 2):
        r = jax.jit(lambda key: _cpx_trial(key, T=120, keep=keep))(jax.random.PRNGKey(3))
        n = r["e"].shape[0] - 1
        e_rec = mhe.error_recursion(jnp.broadcast_to(r["Phi"], (n, 3, 3)),
                                    jnp.broadcast_to(r["G"], (n,) + r["G"].shape),
                                    r["gamma"], r["e"][0], r["zetas"][:n], r["etas"][:n], keep=keep)
        err = float(jnp.abs(e_rec - r["e"]).max())
        print(f"\nProp {'1.4.2 (CPX)' if keep is None else '1.5.1 (SCPX p=2)'}: max deviation {err:.1e}")
        assert err < 1e-10


def test_prop_1_4_3_bound_1000_seeds():
    """||e_k|| <= r^k ||e_0|| + kappa (1 - r^k)/(1 - r) at every k, for gamma above the criterion, 1000 seeds."""

    def one(key):
        r = _cpx_trial(key)
        zeta_bar = jnp.linalg.norm(r["zetas"], axis=1).max()
        eta_bar = jnp.linalg.norm(r["etas"], axis=1).max()
        b = mhe.error_bound(r["gamma"], r["K"], r["lam_min"], zeta_bar, eta_bar)
        n = jnp.arange(r["e"].shape[0])
        en = jnp.linalg.norm(r["e"], axis=1)
        bound = mhe.finite_time_bound(en[0], b.r, b.kappa, n)
        return jnp.max(en[1:] / bound[1:]), b.r, r["crit"], jnp.max(en[-50:]) / b.limit

    keys = jax.random.split(jax.random.PRNGKey(2024), 1000)
    ratio, rr, crit, tail = jax.jit(jax.vmap(one))(keys)
    ratio, rr, crit, tail = map(np.asarray, (ratio, rr, crit, tail))
    print(f"\nProp 1.4.3 on 1000 seeds: max over k >= 1 of ||e_k||/bound_k = {ratio.max():.3f}, r in [{rr.min():.3f}, "
          f"{rr.max():.3f}], criterion gamma in [{crit.min():.3g}, {crit.max():.3g}], "
          f"max tail ||e|| / (kappa/(1-r)) = {tail.max():.3f}")
    assert np.all(rr < 1.0)
    assert np.all(crit > 0)  # the random systems are unstable: the criterion is never vacuous
    assert np.all(ratio <= 1.0 + 1e-12)


def test_prop_1_4_3_criterion_dip():
    """Thesis §3.3: the criterion for CPX on the DIP (1 ms, outputs xc, alpha, theta) is gamma >= 24400."""
    plant = dip.DIP()
    A, B = linearize(plant, jnp.zeros(6), 0.0)
    A = np.asarray(A)
    h = 1e-3
    C = np.zeros((3, 6))
    for i, name in enumerate(("xc", "alpha", "theta")):
        C[i, plant.index(name)] = 1.0
    gamma, K, lam_min = mhe.cpx_gamma_criterion(jnp.asarray(sla.expm(A * h)), jnp.asarray(sla.expm(-A * h)),
                                                jnp.asarray(C))
    dev = abs(float(gamma) - 24400.0) / 24400.0
    print(f"\nProp 1.4.3 criterion for the DIP: gamma > {float(gamma):.1f} (||Phi|| = {float(K):.6f}, "
          f"lambda_min = {float(lam_min):.4e}); thesis 24400; deviation {100 * dev:.2f}%")
    assert dev < 0.02


def test_criteria_formulas():
    # Prop 1.4.3: r < 1 exactly when gamma exceeds the criterion
    K, lam = 1.3, 0.02
    g = float(mhe.gamma_criterion(K, lam))
    assert abs(K / (1 + g * lam) - 1.0) < 1e-12
    assert float(mhe.gamma_criterion(0.9, lam)) == 0.0
    # Prop 1.5.2: r = K/(1 + gamma lambda_p) + alpha hits 1 at the criterion
    alpha = 0.3
    gs = float(mhe.gamma_criterion_subspace(K, lam, alpha))
    b = mhe.error_bound_subspace(gs, K, lam, alpha, 0.1, 0.1)
    assert abs(float(b.r) - 1.0) < 1e-12
    b = mhe.error_bound(2 * g, K, lam, 0.1, 0.05)
    assert abs(float(b.limit) - (K * 0.1 + 0.05) / (1 - K / (1 + 2 * g * lam))) < 1e-12
