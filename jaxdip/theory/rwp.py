"""Analytic results of Aranovskiy et al. (reaction-wheel pendulum, biased angle sensor) as functions.

Reduced state x = [theta, theta', theta_r'], linearised model (4) with the input column from (2)-(3)
(B = [0, -k/J, k/J + k/Jr]; docs/models.md), law u = -K x, K = [k1, k2, k3] (Table 2: [-582, -83, -1.2]).

Equilibria under a sensor bias d (y = theta + d):

* (7)  law (5) on y:                            x_eq = (A - BK)^-1 B K [d, 0, 0]      = [0, 0, -d k1/k3].
* (15) differentiator (10) fed with y: steady velocity error (for constant theta, cos(theta) > 0)
       e_p2^0 = k_p1 (a1 cos(theta) |d| / k_p2)^(α_p / (2α_p - 1)) sgn(d);
       wheel (12): e_r2^0 = -k_r1 (a1 cos(theta) |d| / k_r2)^(α_r / (2α_r - 1)) sgn(d) (= -e_p2^0 for equal gains).
* (16) law (8) with these errors:               x_eq = (A - BK)^-1 B K [d, e_p2^0, e_r2^0]
                                                     = [0, 0, e_p2^0 (k3 - k2)/k3 - d k1/k3]   (equal gains).
  The printed (16) stacks a 4-vector [d, e_p2^0, 0, e_r2^0] against the 3-state K; the derivation (u = 0 at the
  equilibrium, since (b2 + b3) u = (k/Jr) u = 0) uses the 3-vector. The general form for unequal gains is
  x3 = -(k1 d + k2 e_p2^0 + k3 e_r2^0)/k3.

Proposition 2 (low-pass bias observer (17) with law (18)): with d~ = d - d̂, d~' = -γ_d d~ - γ_d x1, so

    [x; d~]' = F [x; d~],   F = [[A - BK, -k1 B], [-γ_d e1^T, -γ_d]]

(the printed F has 0 where -γ_d belongs; the printed polynomial keeps it; docs/models.md). det(sI - F) = (s + γ_d)
(s^3 + m1 s^2 + m2 s + m3) + (k k1/J) γ_d s = s^4 + b1 s^3 + b2 s^2 + b3 s + b4 with m1, m2, m3 and b1..b4 as
printed. b3 > 0 <=> γ_d < -k k3/Jr = γ̄_d,1; the last Routh condition (b1 b2 - b3) b3 - b1^2 b4 > 0 is a cubic in
γ_d whose smallest positive root is γ̄_d,2; γ̄_d = min(γ̄_d,1, γ̄_d,2). ``gamma_bar_routh`` follows that route,
``gamma_bar_eig`` bisects on the largest real part of eig(F).

Proposition 3 (joint observer (24)): first-order expansion (26) around α_p = 1 with

    A0(c) = [[-k_p1 + L0 k_p2, 1, 0], [-k_p2, 0, -a1 c], [L0 k_p2, 0, 0]],
    A1    = [[L0 k_p2 - k_p1/2, 0, 0], [-k_p2, 0, 0], [L0 k_p2, 0, 0]],

A_m = A0(c0), A_M = A0(1), and the matrix inequalities (27) in P = P^T > 0 for given (L0, γ, μ):

    Q := -(P A1 + A1^T P) >= 0,   P A_m + A_m^T P + μ Q + γ P <= 0,   P A_M + A_M^T P + μ Q + γ P <= 0,

with the domain-of-attraction size s_M = exp(μ / (2 Δα)), Δα = 1 - α_p (28), and Ω = {s^T P s < C},
C = s_M^2 / (e1^T P^-1 e1) (the largest C with s^T P s < C => s1^2 < s_M^2). c0 (Assumption 2) is not given in
the paper; it is an argument here.

Where A1 comes from: d/dα ⌈s1⌋^α = ln|s1| ⌈s1⌋^α = (1/2) ln(s1^2) s1 at α = 1 and d/dα ⌈s1⌋^(2α-1) = ln(s1^2) s1,
so the first-order terms in Δα = 1 - α of (25) are -ln(s1^2) Δα A1 s with A1's first column
[L0 k_p2 - k_p1/2, -k_p2, L0 k_p2], as printed.

Q >= 0 has structure: A1 = a e1^T has rank one, so P A1 + A1^T P = (P a) e1^T + e1 (P a)^T is negative
semi-definite only if P a = -(q/2) e1 with q >= 0, and then Q = q e1 e1^T. The solver does not get this hint;
``check_lmi`` verifies its answer by eigenvalues.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import jax.numpy as jnp
import numpy as np

from jaxdip.plants import rwp



def first_instability(unstable, gamma_max: float, grid: int, tol: float) -> float:
    """Smallest gain in (1e-6, gamma_max] where ``unstable(gain)`` turns true: a log grid brackets the first
    crossing, bisection refines it (inf if none on the grid, 0 if unstable from the start)."""
    gs = np.geomspace(1e-6, gamma_max, grid)
    flags = np.array([unstable(g) for g in gs])
    if not flags.any():
        return math.inf
    i = int(np.argmax(flags))
    if i == 0:
        return 0.0
    lo, hi = gs[i - 1], gs[i]
    while hi - lo > tol * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if unstable(mid) else (mid, hi)
    return 0.5 * (lo + hi)

def _k(K):
    K = jnp.reshape(jnp.asarray(K, dtype=jnp.float64), (-1,))
    return K[0], K[1], K[2]


def a1(p: rwp.RWP):
    return rwp.mass_moment(p) * p.g / rwp.inertia(p)


def closed_loop_matrix(p: rwp.RWP, K):
    A, B = rwp.reduced_linear_model(p)
    K = jnp.reshape(jnp.asarray(K, dtype=jnp.float64), (1, 3))
    return A - B @ K


# ---- equilibria (7), (15), (16) ---------------------------------------------------------------------------


def equilibrium_biased_feedback(p: rwp.RWP, K, d):
    """(7) solved numerically: (A - BK)^-1 B K [d, 0, 0]."""
    return equilibrium_with_offsets(p, K, jnp.zeros(3).at[0].set(d))


def equilibrium_with_offsets(p: rwp.RWP, K, delta):
    """x with (A - BK) x = B K delta: the equilibrium of u = -K (x + delta) on (4)."""
    A, B = rwp.reduced_linear_model(p)
    Kr = jnp.reshape(jnp.asarray(K, dtype=jnp.float64), (1, 3))
    return jnp.linalg.solve(A - B @ Kr, (B @ Kr @ jnp.asarray(delta, dtype=jnp.float64)))


def thetar_dot_biased_feedback(K, d):
    """(7) in closed form: theta_r' = -d k1/k3."""
    k1, _, k3 = _k(K)
    return -d * k1 / k3


def homd_steady_error(k1, k2, alpha, a1_value, d, cos_theta=1.0):
    """(15): e_p2^0 = k1 (a1 cos(theta) |d| / k2)^(α/(2α-1)) sgn(d) for the pendulum differentiator (10)."""
    base = a1_value * cos_theta * jnp.abs(d) / k2
    return k1 * base ** (alpha / (2.0 * alpha - 1.0)) * jnp.sign(d)


def wheel_steady_error(k1, k2, alpha, a1_value, d, cos_theta=1.0):
    """Wheel differentiator (12) under the pendulum bias: e_r2^0 = -(15) with the wheel's gains."""
    return -homd_steady_error(k1, k2, alpha, a1_value, d, cos_theta)


def thetar_dot_biased_homd(K, d, ep2, er2=None):
    """(16): theta_r' at the equilibrium of law (8) with velocity errors ep2, er2 (er2 = -ep2 by default):
    -(k1 d + k2 ep2 + k3 er2)/k3, = ep2 (k3 - k2)/k3 - d k1/k3 for er2 = -ep2."""
    k1, k2, k3 = _k(K)
    er2 = -ep2 if er2 is None else er2
    return -(k1 * d + k2 * ep2 + k3 * er2) / k3


# ---- Proposition 2 ------------------------------------------------------------------------------------------


def char_coeffs(p: rwp.RWP, K):
    """(m1, m2, m3) of det(sI - (A - BK)) = s^3 + m1 s^2 + m2 s + m3, as printed in the proof of Prop. 2."""
    k1, k2, k3 = _k(K)
    J = rwp.inertia(p)
    ml = rwp.mass_moment(p)
    m1 = p.k * k3 / p.Jr + p.k * k3 / J - p.k * k2 / J
    m2 = -p.k * k1 / J - p.g * ml / J
    m3 = -p.g * p.k * k3 * ml / (J * p.Jr)
    return m1, m2, m3


def lowpass_F(p: rwp.RWP, K, gamma_d):
    """F of Proposition 2 with the -γ_d on its diagonal (state [x, d~])."""
    A, B = rwp.reduced_linear_model(p)
    k1, _, _ = _k(K)
    M = closed_loop_matrix(p, K)
    top = jnp.concatenate([M, -k1 * B], axis=1)
    bottom = jnp.concatenate([jnp.stack([-gamma_d, 0.0 * gamma_d, 0.0 * gamma_d]), jnp.reshape(-gamma_d, (1,))])
    return jnp.concatenate([top, bottom[None, :]], axis=0)


def lowpass_char_coeffs(p: rwp.RWP, K, gamma_d):
    """(b1, b2, b3, b4) of det(sI - F), as printed."""
    k1, _, _ = _k(K)
    m1, m2, m3 = char_coeffs(p, K)
    J = rwp.inertia(p)
    b1 = gamma_d + m1
    b2 = gamma_d * m1 + m2
    b3 = gamma_d * m2 + m3 + p.k * k1 / J * gamma_d
    b4 = gamma_d * m3
    return b1, b2, b3, b4


def routh_cubic(p: rwp.RWP, K):
    """Coefficients (ascending powers of γ_d) of (b1 b2 - b3) b3 - b1^2 b4, a cubic in γ_d."""
    k1, _, _ = _k(K)
    m1, m2, m3 = (float(v) for v in char_coeffs(p, K))
    c = float(p.k * k1 / rwp.inertia(p))
    P = np.polynomial.polynomial
    b1, b2, b3, b4 = [m1, 1.0], [m2, m1], [m3, m2 + c], [0.0, m3]
    return P.polysub(P.polymul(P.polysub(P.polymul(b1, b2), b3), b3), P.polymul(P.polymul(b1, b1), b4))


class GammaBar(NamedTuple):
    gamma_bar: float
    gamma_bar_1: float  # from b3 > 0
    gamma_bar_2: float  # smallest positive real root of the Routh cubic


def gamma_bar_routh(p: rwp.RWP, K) -> GammaBar:
    """γ̄_d of Proposition 2 by the Routh route (the proof's construction)."""
    k1, k2, k3 = _k(K)
    m1, m2, m3 = (float(v) for v in char_coeffs(p, K))
    if not (m1 > 0 and m2 > 0 and m3 > 0 and m1 * m2 > m3):
        raise ValueError("A - BK is not Hurwitz (Routh conditions (19) fail)")
    g1 = float(-p.k * k3 / p.Jr)
    roots = np.polynomial.polynomial.polyroots(routh_cubic(p, K))
    real_pos = sorted(r.real for r in roots if abs(r.imag) <= 1e-9 * max(1.0, abs(r)) and r.real > 0)
    g2 = real_pos[0] if real_pos else math.inf
    return GammaBar(min(g1, g2), g1, g2)


def max_real_eig_F(p: rwp.RWP, K, gamma_d) -> float:
    return float(np.max(np.linalg.eigvals(np.asarray(lowpass_F(p, K, gamma_d))).real))


def gamma_bar_eig(p: rwp.RWP, K, gamma_max: float = 1e3, grid: int = 2000, tol: float = 1e-12) -> float:
    """γ̄_d as the smallest γ_d > 0 where F stops being Hurwitz: a log grid to bracket, then bisection."""
    F0 = np.asarray(lowpass_F(p, K, 0.0))
    e1 = np.zeros(4)
    e1[0] = e1[3] = 1.0  # F(γ) = F(0) - γ e4 [1, 0, 0, 1]

    def unstable(g):
        F = F0.copy()
        F[3] -= g * e1
        return float(np.max(np.linalg.eigvals(F).real)) >= 0

    return first_instability(unstable, gamma_max, grid, tol)


# ---- Proposition 3: the matrix inequalities (27) -----------------------------------------------------------


def lmi_matrices(L0, kp1, kp2, a1_value, c0):
    """(A_m, A_M, A1) of (26)-(27) as NumPy arrays."""
    def A0(c):
        return np.array([[-kp1 + L0 * kp2, 1.0, 0.0], [-kp2, 0.0, -a1_value * c], [L0 * kp2, 0.0, 0.0]])

    A1 = np.array([[L0 * kp2 - 0.5 * kp1, 0.0, 0.0], [-kp2, 0.0, 0.0], [L0 * kp2, 0.0, 0.0]])
    return A0(c0), A0(1.0), A1


def s_M(mu, alpha):
    """(28): s_M = exp(μ / (2 Δα)), Δα = 1 - α_p (> 0)."""
    return math.exp(mu / (2.0 * (1.0 - alpha)))


def lmi_expressions(P, L0, gamma, mu, kp1, kp2, a1_value, c0):
    """The three matrices of (27) for a given P: (Q, M_m, M_M) (feasible iff Q >= 0, M_m <= 0, M_M <= 0)."""
    Am, AM, A1 = lmi_matrices(L0, kp1, kp2, a1_value, c0)
    P = np.asarray(P, dtype=np.float64)
    Q = -(P @ A1 + A1.T @ P)
    Mm = P @ Am + Am.T @ P + mu * Q + gamma * P
    MM = P @ AM + AM.T @ P + mu * Q + gamma * P
    return Q, Mm, MM


class LMICheck(NamedTuple):
    feasible: bool
    min_eig_P: float
    min_eig_Q: float
    max_eig_Mm: float
    max_eig_MM: float
    tol: float


def check_lmi(P, L0, gamma, mu, kp1, kp2, a1_value, c0, rtol: float = 1e-7) -> LMICheck:
    """Independent check of a candidate P by eigenvalues (NumPy), tolerances relative to ||P||_2."""
    P = np.asarray(P, dtype=np.float64)
    P = 0.5 * (P + P.T)
    Q, Mm, MM = lmi_expressions(P, L0, gamma, mu, kp1, kp2, a1_value, c0)
    sym = lambda X: 0.5 * (X + X.T)  # noqa: E731
    eP = np.linalg.eigvalsh(P)
    tol = rtol * float(np.max(np.abs(eP)))
    r = LMICheck(
        feasible=False,
        min_eig_P=float(eP.min()),
        min_eig_Q=float(np.linalg.eigvalsh(sym(Q)).min()),
        max_eig_Mm=float(np.linalg.eigvalsh(sym(Mm)).max()),
        max_eig_MM=float(np.linalg.eigvalsh(sym(MM)).max()),
        tol=tol,
    )
    ok = r.min_eig_P > tol and r.min_eig_Q >= -tol and r.max_eig_Mm <= tol and r.max_eig_MM <= tol
    return r._replace(feasible=bool(ok))


class LMIResult(NamedTuple):
    status: str  # solver status
    feasible: bool  # solver margin > 0 and the eigenvalue check passes
    margin: float  # t* of the normalised problem (> 0: strictly feasible in P > 0 and the two decrease LMIs)
    P: Optional[np.ndarray]
    check: Optional[LMICheck]
    s_M: float
    C: float  # Ω = {s^T P s < C}
    solver: str


def have_cvxpy() -> bool:
    try:
        import cvxpy  # noqa: F401
    except ImportError:
        return False
    return True


def solve_lmi(L0, gamma, mu, kp1, kp2, alpha, a1_value, c0, solver: Optional[str] = None) -> LMIResult:
    """Solve (27) for P with an SDP solver (cvxpy; optional extra ``jaxdip[lmi]``).

    The inequalities are homogeneous in P, so the problem is normalised: maximise t subject to trace(P) = 1,
    P >= t I, Q >= 0, and both decrease inequalities <= -t I. (27) is feasible with P > 0 iff t* > 0 (the
    non-strict decrease inequalities then hold with margin). The answer is checked by ``check_lmi``.
    """
    import cvxpy as cp

    Am, AM, A1 = lmi_matrices(L0, kp1, kp2, a1_value, c0)
    P = cp.Variable((3, 3), symmetric=True)
    t = cp.Variable()
    Q = -(P @ A1 + A1.T @ P)
    I3 = np.eye(3)
    cons = [cp.trace(P) == 1, P >> t * I3, 0.5 * (Q + Q.T) >> 0]
    for A in (Am, AM):
        M = P @ A + A.T @ P + mu * Q + gamma * P
        cons.append(0.5 * (M + M.T) << -t * I3)
    prob = cp.Problem(cp.Maximize(t), cons)
    names = cp.installed_solvers()
    if solver is None:
        solver = next((s for s in ("CLARABEL", "SCS", "CVXOPT", "MOSEK") if s in names), None)
        if solver is None:
            raise RuntimeError(f"no SDP-capable cvxpy solver installed (have {names})")
    prob.solve(solver=solver)
    sm = s_M(mu, alpha)
    if P.value is None or t.value is None:
        return LMIResult(str(prob.status), False, float("nan"), None, None, sm, float("nan"), solver)
    Pv = 0.5 * (P.value + P.value.T)
    chk = check_lmi(Pv, L0, gamma, mu, kp1, kp2, a1_value, c0)
    margin = float(t.value)
    feasible = bool(margin > 0 and chk.feasible)
    C = sm**2 / float(np.linalg.solve(Pv, np.eye(3)[:, 0])[0]) if chk.min_eig_P > 0 else float("nan")
    return LMIResult(str(prob.status), feasible, margin, Pv, chk, sm, C, solver)


def mu_max(L0, gamma, kp1, kp2, alpha, a1_value, c0, lo: float = -5.0, hi: float = 1.0, iters: int = 30,
           solver: Optional[str] = None) -> float:
    """Largest μ for which (27) is feasible (bisection on μ; feasibility is monotone: larger μ is harder)."""
    if not solve_lmi(L0, gamma, lo, kp1, kp2, alpha, a1_value, c0, solver).feasible:
        return float("nan")
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if solve_lmi(L0, gamma, mid, kp1, kp2, alpha, a1_value, c0, solver).feasible:
            lo = mid
        else:
            hi = mid
    return lo


# ---- the low-pass observer with the differentiators in the loop (linear, α = 1) ------------------------------


def lowpass_homd_linear_matrix(p: rwp.RWP, K, kp, kr, gamma_d):
    """Closed-loop matrix of (4) + (10) + (12) + (17) + law (23) for α_p = α_r = 1 (where the loop is linear).

    This is the loop of the low-pass experiment (Fig. 5), not Proposition 2's (which has exact velocities).
    Both differentiators run on y - d̂; linearised at the upright equilibrium. State (the wheel angle enters only
    through the wheel observer's innovation, so x̂_r1 and theta_r are replaced by e_r1 = x̂_r1 - theta_r, which
    removes the structural zero eigenvalue of the free wheel angle):

        w = [theta, theta', theta_r', x̂_p1, x̂_p2, e_r1, x̂_r2, d̂],   input d (constant),
        y = theta + d,  θc = y - d̂,  u = -(k1 θc + k2 x̂_p2 + k3 x̂_r2),
        theta'' = a1 theta + b2 u,  theta_r'' = -a1 theta + b3 u,       b2 = -k/J, b3 = (J + Jr) k/(J Jr),
        x̂_p1' = x̂_p2 - kp1 (x̂_p1 - θc),  x̂_p2' = b2 u + a1 θc - kp2 (x̂_p1 - θc),
        e_r1'  = x̂_r2 - kr1 e_r1 - theta_r',  x̂_r2' = b3 u - a1 θc - kr2 e_r1,
        d̂' = γ_d (y - d̂).

    ``kp`` = (k_p1, k_p2), ``kr`` = (k_r1, k_r2). Returns (M, g) with w' = M w + g d.
    """
    k1, k2, k3 = (float(v) for v in _k(K))
    a = float(a1(p))
    J = float(rwp.inertia(p))
    b2 = -float(p.k) / J
    b3 = (J + float(p.Jr)) * float(p.k) / (J * float(p.Jr))
    kp1, kp2 = (float(v) for v in kp)
    kr1, kr2 = (float(v) for v in kr)
    g = float(gamma_d)
    n = 8
    # every quantity as a row vector over [w, d]
    e = np.eye(n + 1)
    th, thd, thrd, xp1, xp2, er1, xr2, dh, d = (e[i] for i in range(n + 1))
    thc = th + d - dh
    u = -(k1 * thc + k2 * xp2 + k3 * xr2)
    rows = [
        thd,
        a * th + b2 * u,
        -a * th + b3 * u,
        xp2 - kp1 * (xp1 - thc),
        b2 * u + a * thc - kp2 * (xp1 - thc),
        xr2 - kr1 * er1 - thrd,
        b3 * u - a * thc - kr2 * er1,
        g * (th + d - dh),
    ]
    R = np.stack(rows)
    return R[:, :n], R[:, n]


def gamma_bar_lowpass_homd_linear(p: rwp.RWP, K, kp, kr, gamma_max: float = 100.0, grid: int = 400,
                                  tol: float = 1e-12) -> float:
    """Smallest γ_d > 0 at which ``lowpass_homd_linear_matrix`` stops being Hurwitz (log grid + bisection)."""
    def unstable(gm):
        return float(np.max(np.linalg.eigvals(lowpass_homd_linear_matrix(p, K, kp, kr, gm)[0]).real)) >= 0

    return first_instability(unstable, gamma_max, grid, tol)
