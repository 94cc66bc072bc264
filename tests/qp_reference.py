"""A certified reference solution of a small convex QP (SLSQP for the active set, then the exact KKT solve),
shared by the constrained MHE tests."""

import numpy as np


def kkt_reference(A, b, G, lo, hi, x_start):
    """The minimiser of ||A x - b||^2 subject to lo <= G x <= hi, certified: the active set of an approximate
    solution (scipy's SLSQP) is fixed and the equality-constrained KKT system solved exactly in NumPy; the
    answer must then be feasible and its multipliers of the right sign (KKT, sufficient for a convex QP)."""
    from scipy.optimize import minimize

    fin_lo, fin_hi = np.isfinite(lo), np.isfinite(hi)
    cons = [{"type": "ineq", "fun": lambda x: (G @ x - lo)[fin_lo], "jac": lambda x: G[fin_lo]},
            {"type": "ineq", "fun": lambda x: (hi - G @ x)[fin_hi], "jac": lambda x: -G[fin_hi]}]
    s = np.linalg.norm(A, 2) ** 2  # scaled so the objective is O(1) for SLSQP's absolute tolerance
    r = minimize(lambda x: 0.5 * np.sum((A @ x - b) ** 2) / s, x_start, jac=lambda x: A.T @ (A @ x - b) / s,
                 constraints=cons, method="SLSQP", options={"ftol": 1e-15, "maxiter": 1000})
    gx = G @ r.x
    scale = 1e-7 * max(1.0, np.max(np.abs(gx)))
    up, dn = fin_hi & (gx > hi - scale), fin_lo & (gx < lo + scale)
    act = up | dn
    H, g = A.T @ A, A.T @ b
    n, Ga = H.shape[0], G[act]
    kkt = np.block([[H, Ga.T], [Ga, np.zeros((Ga.shape[0],) * 2)]])
    # least squares: with dependent active rows (the hard model repeats a row for every window state when the
    # model leaves that combination unchanged) x is still unique and lam the minimum-norm multiplier
    sol = np.linalg.lstsq(kkt, np.concatenate([g, np.where(up, hi, lo)[act]]), rcond=None)[0]
    x, lam = sol[:n], sol[n:]
    assert np.all(G @ x <= hi + 1e-12) and np.all(G @ x >= lo - 1e-12)
    sign = np.where(up[act], 1.0, -1.0)  # H x - g + Ga^T lam = 0: lam >= 0 at an upper bound, <= 0 at a lower
    assert np.all(sign * lam >= -1e-9 * np.max(np.abs(g)))
    assert np.max(np.abs(r.x - x)) < 1e-5  # scipy found this active set itself
    return x, int(act.sum())
