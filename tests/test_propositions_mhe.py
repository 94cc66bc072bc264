"""King's thesis, chapter 1: Propositions 1.3.3 (the proximity inequality) and 1.5.2 (the subspace estimator's
error bound), checked numerically on the thesis's systems against independent computations.

Systems: the centred CPX functional of the DIP at 1 ms (outputs xc, alpha, theta; the setting of Prop. 1.4.3) and
the Lorenz system of §1.6. References: NumPy/SciPy linear algebra and matrix exponentials, SciPy's minimiser, and
the subspace estimator (1.26) and the Lorenz system written again in NumPy. Prop. 1.5.1 (the SCPX error
recursion) is tests/test_theory_mhe.py::test_prop_1_4_2_cpx_and_1_5_1_scpx.
"""

import numpy as np
import scipy.linalg as sla
from scipy.optimize import minimize

import jax.numpy as jnp

import jaxdip  # noqa: F401  (float64)
from jaxdip.estimators.proximal import prox_ls
from jaxdip.plants import dip, lorenz
from jaxdip.engine.roles import linearize
from jaxdip.theory import mhe

H_DIP = 1e-3


def _dip_discrete():
    """(Phi, C) of the printed DIP at upright, ZOH at 1 ms (SciPy expm), C picking xc, alpha, theta."""
    plant = dip.DIP()
    A = np.asarray(linearize(plant, jnp.zeros(6), jnp.zeros(1))[0])
    C = np.zeros((3, 6))
    for i, name in enumerate(("xc", "alpha", "theta")):
        C[i, plant.index(name)] = 1.0
    return sla.expm(A * H_DIP), C


# ---- Prop. 1.3.3: the proximity inequality ------------------------------------------------------------------


def test_prop_1_3_3_proximity_inequality():
    """||y - p||^2 <= ||x - y||^2 - 2 gamma (phi(p) - phi(y)) for p = Prox_{gamma phi}(x), every y.

    phi: the DIP's centred least-squares functional phi(z) = 1/2 ||G z - q||^2, G = [C Phi^-1; C; C Phi] (p from
    jaxdip's prox_ls, checked first against the normal equations solved by NumPy and SciPy's minimiser), at the
    thesis's weights 150 and 24400, and the convex nonsmooth phi = ||z||_1 (p by soft thresholding, checked
    against SciPy's minimiser). The proposition needs phi convex (Gamma_0): for the double well (z^2 - 1)^2 on R the
    same inequality fails at some (x, y), which is what makes the check able to fail."""
    rng = np.random.default_rng(11)
    Phi, C = _dip_discrete()
    G = np.vstack([C @ np.linalg.inv(Phi), C, C @ Phi])
    worst = -np.inf
    for gamma in (150.0, 24400.0):
        for _ in range(20):
            q, x = rng.normal(size=9), rng.normal(size=6)
            p = np.asarray(prox_ls(jnp.asarray(G), jnp.asarray(q), jnp.asarray(x), gamma))
            np.testing.assert_allclose(p, np.linalg.solve(G.T @ G + np.eye(6) / gamma, G.T @ q + x / gamma),
                                       rtol=1e-8, atol=1e-10)
            phi = lambda z: 0.5 * np.sum((G @ z - q) ** 2)  # noqa: E731
            for y in rng.normal(size=(20, 6)) * rng.uniform(0.01, 10.0, size=(20, 1)):
                lhs, rhs = np.sum((y - p) ** 2), np.sum((x - y) ** 2) - 2 * gamma * (phi(p) - phi(y))
                worst = max(worst, (lhs - rhs) / max(1.0, abs(rhs)))
    res = minimize(lambda z: 0.5 * np.sum((G @ z - q) ** 2) + np.sum((z - x) ** 2) / (2 * 150.0), x,
                   jac=lambda z: G.T @ (G @ z - q) + (z - x) / 150.0, method="BFGS", options={"gtol": 1e-12})
    np.testing.assert_allclose(res.x, np.asarray(prox_ls(jnp.asarray(G), jnp.asarray(q), jnp.asarray(x), 150.0)),
                               atol=1e-5)
    assert worst <= 1e-9

    for gamma in (0.3, 2.0):
        for _ in range(50):
            x = 3 * rng.normal(size=4)
            p = np.sign(x) * np.maximum(np.abs(x) - gamma, 0.0)
            if _ == 0:
                ref = minimize(lambda z: np.abs(z).sum() + np.sum((z - x) ** 2) / (2 * gamma), x,
                               method="Powell", options={"xtol": 1e-10, "ftol": 1e-14})
                np.testing.assert_allclose(ref.x, p, atol=1e-5)
            for y in 3 * rng.normal(size=(20, 4)):
                lhs = np.sum((y - p) ** 2)
                rhs = np.sum((x - y) ** 2) - 2 * gamma * (np.abs(p).sum() - np.abs(y).sum())
                assert lhs <= rhs + 1e-12

    zs = np.linspace(-3, 3, 600001)
    well = (zs**2 - 1) ** 2
    violated = 0
    for x in np.linspace(-2, 2, 41):
        gamma = 0.5
        p = zs[np.argmin(gamma * well + 0.5 * (zs - x) ** 2)]
        for y in np.linspace(-2, 2, 41):
            lhs = (y - p) ** 2
            rhs = (x - y) ** 2 - 2 * gamma * ((p**2 - 1) ** 2 - (y**2 - 1) ** 2)
            violated += lhs > rhs + 1e-6
    assert violated > 0


# ---- Prop. 1.5.2: the subspace (SCPX) error bound -----------------------------------------------------------


def _scpx_run(rng, a, T=60, d=4, p=3, l=6):
    """A random LTI system whose dropped direction of G^T G is mapped by Phi to length ``a`` (so Prop. 1.5.2's
    alpha is ``a``), and the subspace estimator (1.26) written out in NumPy; returns what the bound needs.
    T is short because the open-loop state grows (up to ~1.4x a step): over 150 steps x_k reaches 1e19 and
    xhat_k - x_k would be lost to rounding."""
    G = rng.normal(size=(l, d))
    lam, U = np.linalg.eigh(G.T @ G)
    lam, U = lam[::-1], U[:, ::-1]  # descending: the first p are kept
    A = rng.normal(size=(d, d))
    A -= (np.linalg.eigvals(A).real.max() - 0.5) * np.eye(d)  # unstable: max Re = 0.5
    Phi = sla.expm(0.2 * A)
    Upc = U[:, p:]
    Phi = Phi + ((a / np.linalg.norm(Phi @ Upc)) - 1.0) * (Phi @ Upc) @ Upc.T
    crit, K = None, np.linalg.norm(Phi, 2)
    alpha = np.linalg.norm(Phi @ Upc @ Upc.T, 2)
    lam_p = lam[p - 1]
    if alpha < 1:
        crit = max((K - (1 - alpha)) / (lam_p * (1 - alpha)), 0.0)
    gamma = (crit if crit is not None else 1.0) * rng.uniform(1.05, 4.0) + 1e-3
    eta = 0.05 * rng.uniform(-1, 1, size=(T, d))
    v = 0.2 * rng.uniform(-1, 1, size=(T, l))
    zeta = np.linalg.lstsq(G, v.T, rcond=None)[0].T
    x, xhat = rng.normal(size=d), rng.normal(size=d) * 3
    Up, Lp = U[:, :p], lam[:p]
    errs = []
    for k in range(T):
        errs.append(xhat - x)
        # (1.26): p_k = U_p (L_p + I/gamma)^-1 U_p^T (U_p L_p U_p^T (x + zeta) + xhat/gamma) + U_pc U_pc^T xhat
        pk = Up @ ((Up.T @ (Up @ (Lp * (Up.T @ (x + zeta[k]))) + xhat / gamma)) / (Lp + 1 / gamma)) \
            + Upc @ (Upc.T @ xhat)
        x, xhat = Phi @ x + eta[k], Phi @ pk
    return dict(e=np.array(errs), Phi=Phi, G=G, p=p, gamma=gamma, K=K, lam_p=lam_p, alpha=alpha, crit=crit,
                zeta_bar=np.linalg.norm(zeta, axis=1).max(), eta_bar=np.linalg.norm(eta, axis=1).max())


def test_prop_1_5_2_subspace_bound():
    """With ||Phi U_pc U_pc^T|| = alpha < 1 and gamma above (K - (1 - alpha))/(lambda_p,min (1 - alpha)), the
    subspace estimator's error obeys ||e_k|| <= r^k ||e_0|| + kappa (1 - r^k)/(1 - r) (the inequality of the
    proof, whose limit is the proposition's kappa/(1 - r)), r = K/(1 + gamma lambda_p,min) + alpha, kappa = K
    zeta_bar + eta_bar; 200 random unstable systems with bounded noise, the estimator simulated in NumPy from
    (1.26), the bound from jaxdip.theory.mhe. With alpha = 1.3 (hypothesis broken) the error in the dropped
    direction grows without bound whatever gamma."""
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(200):
        r = _scpx_run(rng, a=rng.uniform(0.2, 0.9))
        assert abs(float(mhe.subspace_alpha(jnp.asarray(r["Phi"]), jnp.asarray(r["G"]), r["p"])) - r["alpha"]) < 1e-10
        b = mhe.error_bound_subspace(r["gamma"], r["K"], r["lam_p"], r["alpha"], r["zeta_bar"], r["eta_bar"])
        assert abs(float(b.gamma_min) - r["crit"]) < 1e-9 * max(1.0, r["crit"])
        assert float(b.r) < 1
        en = np.linalg.norm(r["e"], axis=1)
        k = np.arange(en.shape[0])
        bound = np.asarray(mhe.finite_time_bound(en[0], b.r, b.kappa, k))
        worst = max(worst, (en[1:] / bound[1:]).max())
    print(f"\nProp 1.5.2: max ||e_k|| / bound_k over 200 systems = {worst:.3f}")
    assert worst <= 1.0 + 1e-12
    grown = [_scpx_run(rng, a=1.3)["e"] for _ in range(5)]
    assert min(np.linalg.norm(e[-1]) / np.linalg.norm(e[0]) for e in grown) > 1e2


def _lorenz_np(x, s=10.0, b=8.0 / 3.0, r=28.0):
    return np.array([s * (x[1] - x[0]), x[0] * (r - x[2]) - x[1], x[0] * x[1] - b * x[2]])


def _lorenz_jac(x, s=10.0, b=8.0 / 3.0, r=28.0):
    return np.array([[-s, s, 0.0], [r - x[2], -1.0, -x[0]], [x[1], x[0], -b]])


def test_prop_1_5_2_hypothesis_on_the_thesis_systems():
    """Prop. 1.5.2's hypothesis on the thesis's systems (centred G = [C Phi^-1; C; C Phi]).

    * Lorenz (§1.6: h = 0.001, outputs yL, zL, SCPX with p = 2, gamma = 50), linearised along 20 time units of a
      NumPy RK4 trajectory from the thesis's x0 = [-8, 7, 27] (Jacobian written by hand, checked against
      jaxdip's vector field by central differences): the dropped direction is nearly xL, which Phi contracts
      (sigma = 10), so alpha = max ||Phi_k U_pc U_pc^T|| = 0.9904 < 1, K_max = 1.0113, lambda_p,min = 3.00 and the
      criterion asks gamma > 34.9: the thesis's gamma = 50 meets it (r = 0.997).
    * DIP (1 ms): for every p < 6 some dropped direction is not contracted (alpha > 1; Phi = I + O(h)), so the
      proposition does not apply to a subspace estimator of the DIP; the thesis runs none there.
    """
    Phi, C = _dip_discrete()
    G = np.vstack([C @ np.linalg.inv(Phi), C, C @ Phi])
    U = np.linalg.eigh(G.T @ G)[1][:, ::-1]
    dip_alpha = [np.linalg.norm(Phi @ U[:, p:] @ U[:, p:].T, 2) for p in range(1, 6)]
    assert min(dip_alpha) > 1.0

    prm = lorenz.Lorenz()
    Cl, h = np.asarray(lorenz.output_matrix()), 1e-3
    x = np.array([-8.0, 7.0, 27.0])
    e = 1e-6 * np.eye(3)
    fd = np.stack([(np.asarray(lorenz.f(prm, jnp.asarray(x + d))) - np.asarray(lorenz.f(prm, jnp.asarray(x - d))))
                   / 2e-6 for d in e], axis=1)
    np.testing.assert_allclose(fd, _lorenz_jac(x), atol=1e-6)
    alpha, K, lam_p = 0.0, 0.0, np.inf
    for k in range(20000):
        if k % 50 == 0:
            Ph = sla.expm(_lorenz_jac(x) * h)
            Gl = np.vstack([Cl @ np.linalg.inv(Ph), Cl, Cl @ Ph])
            lam, U = np.linalg.eigh(Gl.T @ Gl)  # ascending: p = 2 kept drops the first
            alpha = max(alpha, np.linalg.norm(Ph @ U[:, :1] @ U[:, :1].T, 2))
            K, lam_p = max(K, np.linalg.norm(Ph, 2)), min(lam_p, lam[1])
        k1 = _lorenz_np(x)
        k2 = _lorenz_np(x + h / 2 * k1)
        k3 = _lorenz_np(x + h / 2 * k2)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + _lorenz_np(x + h * k3))
    crit = float(mhe.gamma_criterion_subspace(K, lam_p, alpha))
    r = float(mhe.error_bound_subspace(50.0, K, lam_p, alpha, 0.0, 0.0).r)
    print(f"\nProp 1.5.2: DIP alpha (p = 1..5) >= {min(dip_alpha):.4f}; Lorenz alpha {alpha:.4f}, K {K:.4f}, "
          f"lambda_p {lam_p:.3f}, criterion {crit:.1f}, r at gamma 50 {r:.4f}")
    assert alpha < 1 and 30.0 < crit < 50.0 and r < 1
