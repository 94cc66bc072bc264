"""Numerical checks of the proximal point MHE with growing weights (thesis Thm 1.3.2, Prop. 1.4.1) and of the
relaxed projection control with a time-varying weight (Prop. 2.4.2).

Thm 1.3.2: with fitting functionals phi_k whose minimum is 0 at x_k + zeta_k, the observer (1.10)
``p_k = Prox_{gamma_k phi_k}(xhat_k)``, ``xhat_{k+1} = f_k(p_k)`` has phi_k(p_k) -> 0 when
gamma_{k+1} >= max(K_k^2 gamma_k, beta_{k+1} gamma_k K_k^2 / K_{k+1}) and sum 1/gamma_k < inf, with
beta_k = 2 K_k ||zeta_k|| + 2 ||eta_k + zeta_{k+1}|| + 1. Prop. 1.4.1: for the linear least-squares functionals
(1.20), ||p_k - (x_k + zeta_k)|| -> 0 under the same weights.

Prox_{gamma phi}(xhat) = argmin_z phi(z) + ||z - xhat||^2 / (2 gamma). The weights grow geometrically, so the
code carries w_k = 1 / gamma_k (it goes to 0 instead of overflowing). The weight sequence is built from the
trajectory's own constants: K_k is the spectral norm of the one-step map's Jacobian at x_k (a local Lipschitz
constant: the Lorenz map has no global one, so the theorem's (A1) holds only along a bounded trajectory),
zeta_k comes from the minimiser of phi_k, and the growth factor is the largest ratio the theorem asks for over
the trial.

* ``nonlinear_two_measurement``: the Lorenz system (RK4 map over h), y = (yL, zL) with bounded uniform noise,
  the two-measurement functional (1.9) phi_k(z) = ||g(z) - y_k||^2 + ||g(f(z)) - y_{k+1}||^2. (1.9) is not
  convex, so Prox is computed by Gauss-Newton from xhat_k and the minimiser x_k + zeta_k by Gauss-Newton from
  the truth (the local minimum the theorem means); "min phi_k" is that local minimum's value.
* ``linear_least_squares``: (1.20) on an LTI system with a window of outputs; closed form.
* ``relaxed_projection_growth``: Prop. 2.4.2 on a linear system xdot = A x + B u with (2.14); see its docstring.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sla

from jaxdip.plants import lorenz


class GrowthResult(NamedTuple):
    gap_growing: np.ndarray  # (trials,) phi_k(p_k) - min phi_k at the last step, growing gamma_k
    gap_constant: np.ndarray  # the same with gamma_k = gamma_0
    err_growing: np.ndarray  # (trials,) ||p_k - (x_k + zeta_k)|| at the last step, growing gamma_k
    err_constant: np.ndarray
    growth: np.ndarray  # (trials,) the geometric growth factor used (>= every ratio Thm 1.3.2 asks for)
    tail_gap_growing: np.ndarray  # (trials,) max of the gap over the last quarter of the steps
    tail_gap_constant: np.ndarray
    truth_err_growing: np.ndarray  # (trials,) mean ||p_k - x_k|| over the last quarter (error to the true state)
    truth_err_constant: np.ndarray


def _rk4(f, x, h):
    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def lorenz_map(h: float):
    p = lorenz.Lorenz()
    return lambda x: _rk4(lambda z: lorenz.f(p, z), x, h)


def _gauss_newton(res, z0, iters: int):
    def body(z, _):
        r = res(z)
        J = jax.jacfwd(res)(z)
        # a tiny Levenberg term keeps the step defined where J loses rank
        dz = jnp.linalg.solve(J.T @ J + 1e-12 * jnp.eye(z.shape[0]), J.T @ r)
        return z - dz, None

    return jax.lax.scan(body, z0, None, length=iters)[0]


def _thm_growth(Ks, zetas, etas):
    """The smallest constant factor rho with gamma_{k+1} = rho gamma_k meeting Thm 1.3.2 along a trajectory."""
    nz = jnp.linalg.norm(zetas, axis=1)
    beta = 2 * Ks * nz + 2 * jnp.linalg.norm(etas + jnp.roll(zetas, -1, axis=0), axis=1) + 1
    r1 = Ks[:-1] ** 2
    r2 = beta[1:] * Ks[:-1] ** 2 / Ks[1:]
    return jnp.maximum(jnp.max(r1), jnp.max(r2))


def nonlinear_two_measurement(key, *, trials: int = 32, steps: int = 300, h: float = 0.01, eps_bar: float = 0.05,
                              eta_bar: float = 1e-3, xhat_offset: float = 1.0, gamma0: float = 1.0,
                              gn_iters: int = 20) -> GrowthResult:
    """Thm 1.3.2 with (1.9) on the Lorenz map: Monte Carlo over initial states, offsets and bounded noise."""
    f = lorenz_map(h)
    C = jnp.asarray(lorenz.output_matrix())

    def trial(k):
        k0, k1, k2, k3 = jax.random.split(k, 4)
        x0 = jnp.array([1.0, 1.0, 25.0]) + 5.0 * jax.random.normal(k0, (3,))
        # settle onto the attractor first
        x0 = jax.lax.fori_loop(0, 500, lambda i, x: f(x), x0)
        etas = eta_bar * jax.random.uniform(k1, (steps + 1, 3), minval=-1, maxval=1)
        eps = eps_bar * jax.random.uniform(k2, (steps + 2, C.shape[0]), minval=-1, maxval=1)

        def advance(x, eta):
            return f(x) + eta, x

        _, xs = jax.lax.scan(advance, x0, etas)  # x_0 .. x_steps
        xs = jnp.concatenate([xs, f(xs[-1])[None]])
        ys = xs @ C.T + eps
        phi = lambda z, k: jnp.sum((C @ z - ys[k]) ** 2) + jnp.sum((C @ f(z) - ys[k + 1]) ** 2)
        fit = lambda z, k: jnp.concatenate([C @ z - ys[k], C @ f(z) - ys[k + 1]])
        ks = jnp.arange(steps)
        mins = jax.vmap(lambda k: _gauss_newton(lambda z: fit(z, k), xs[k], gn_iters))(ks)
        zetas = mins - xs[:steps]
        phimin = jax.vmap(phi)(mins, ks)
        Ks = jax.vmap(lambda x: jnp.linalg.norm(jax.jacfwd(f)(x), 2))(xs[:steps])
        rho = _thm_growth(Ks, zetas, etas[:steps])
        xhat0 = xs[0] + xhat_offset * jax.random.uniform(k3, (3,), minval=-1, maxval=1)

        def run(rate):
            def body(xhat, k):
                w = (1.0 / gamma0) * rate ** (-k.astype(xhat.dtype))
                p = _gauss_newton(lambda z: jnp.concatenate([fit(z, k), jnp.sqrt(w / 2) * (z - xhat)]), xhat,
                                  gn_iters)
                return f(p), (phi(p, k) - phimin[k], jnp.linalg.norm(p - mins[k]), jnp.linalg.norm(p - xs[k]))

            return jax.lax.scan(body, xhat0, ks)[1]

        gg, eg, tg = run(rho)
        gc, ec, tc = run(jnp.ones(()))
        q = steps - steps // 4
        return gg[-1], gc[-1], eg[-1], ec[-1], rho, gg[q:].max(), gc[q:].max(), tg[q:].mean(), tc[q:].mean()

    out = jax.jit(jax.vmap(trial))(jax.random.split(key, trials))
    return GrowthResult(*(np.asarray(o) for o in out))


def linear_least_squares(key, Phi, C, *, window: int = 3, trials: int = 32, steps: int = 400, eps_bar: float = 1e-3,
                         eta_bar: float = 1e-4, xhat_offset: float = 0.05, gamma0: float = 150.0) -> GrowthResult:
    """Prop. 1.4.1 on x_{k+1} = Phi x_k + eta_k, y_k = C x_k + eps_k: phi_k(z) = 1/2 ||G z - q_k||^2 with
    G = [C; C Phi; ...; C Phi^{window-1}] and q_k the next ``window`` outputs (the state noise inside the window
    is part of the discrepancy zeta_k). The proximal point is (I + gamma G^T G)^{-1} (xhat + gamma G^T q)."""
    Phi, C = jnp.asarray(Phi), jnp.asarray(C)
    d = Phi.shape[0]
    G = jnp.concatenate([C @ jnp.linalg.matrix_power(Phi, i) for i in range(window)])
    K = jnp.linalg.norm(Phi, 2)

    def trial(k):
        k0, k1, k2, k3 = jax.random.split(k, 4)
        x0 = 0.05 * jax.random.normal(k0, (d,))
        etas = eta_bar * jax.random.uniform(k1, (steps + window, d), minval=-1, maxval=1)
        _, xs = jax.lax.scan(lambda x, e: (Phi @ x + e, x), x0, etas)
        ys = xs @ C.T + eps_bar * jax.random.uniform(k2, (steps + window, C.shape[0]), minval=-1, maxval=1)
        ks = jnp.arange(steps)
        qs = jax.vmap(lambda k: jax.lax.dynamic_slice_in_dim(ys, k, window).reshape(-1))(ks)
        mins = jnp.linalg.lstsq(G, qs.T)[0].T  # x_k + zeta_k
        zetas = mins - xs[:steps]
        # f_k(x) = Phi x, so the theorem's eta_k is the state noise (x_{k+1} = f_k(x_k) + eta_k)
        rho = _thm_growth(jnp.full(steps, K), zetas, etas[:steps])
        xhat0 = xs[0] + xhat_offset * jax.random.uniform(k3, (d,), minval=-1, maxval=1)
        GtG = G.T @ G

        def run(rate):
            def body(xhat, k):
                w = (1.0 / gamma0) * rate ** (-k.astype(xhat.dtype))
                p = jnp.linalg.solve(w * jnp.eye(d) + GtG, w * xhat + G.T @ qs[k])
                r = G @ (p - mins[k])
                return Phi @ p, (0.5 * r @ r, jnp.linalg.norm(p - mins[k]), jnp.linalg.norm(p - xs[k]))

            return jax.lax.scan(body, xhat0, ks)[1]

        gg, eg, tg = run(rho)
        gc, ec, tc = run(jnp.ones(()))
        q = steps - steps // 4
        return gg[-1], gc[-1], eg[-1], ec[-1], rho, gg[q:].max(), gc[q:].max(), tg[q:].mean(), tc[q:].mean()

    out = jax.jit(jax.vmap(trial))(jax.random.split(key, trials))
    return GrowthResult(*(np.asarray(o) for o in out))


# ---- Prop. 2.4.2 ---------------------------------------------------------------------------------------------


def rp_closed_loop(A, B, P, gamma):
    """The linear closed loop of (2.14): A - B (B^T P B)^{-1} B^T P (gamma I + A)."""
    Bt = B.T @ P
    return A - B @ np.linalg.solve(Bt @ B, Bt @ (gamma * np.eye(A.shape[0]) + A))


def decay_rate(A, B, P, gamma) -> float:
    """The largest value of (d/dt 1/2 x^T P x) / (x^T P x) over x != 0 under (2.14) with this gamma: the
    largest eigenvalue of sym(P A_cl) relative to P. Negative: ||x||_P decays at least at that rate."""
    Acl = rp_closed_loop(A, B, P, gamma)
    M = 0.5 * (P @ Acl + Acl.T @ P)
    return float(sla.eigh(M, P, eigvals_only=True).max())


def smallest_zeta(A, B, P, lo: float = 1e-3, hi: float = 1e7, tol: float = 1e-9) -> float:
    """The smallest constant weight zeta for which P is exponentially stabilising in the sense of Def. 2.4.1
    (decay_rate < 0), by bisection on log(gamma) (the rate is non-increasing in gamma: the gamma term of
    sym(P A_cl) is -gamma P B (B^T P B)^{-1} B^T P, negative semidefinite)."""
    if decay_rate(A, B, P, hi) >= 0:
        return float("inf")
    while np.log(hi / lo) > tol:
        mid = np.sqrt(lo * hi)
        lo, hi = (lo, mid) if decay_rate(A, B, P, mid) < 0 else (mid, hi)
    return hi


class RPGrowth(NamedTuple):
    zeta: float  # the smallest stabilising constant weight (Def. 2.4.1 read with gamma = zeta)
    alpha: float  # the decay rate at 1.01 zeta (d/dt 1/2 ||x||_P^2 <= -alpha ||x||_P^2)
    rates: np.ndarray  # decay_rate at each gamma of gammas (all must be <= -alpha)
    gammas: np.ndarray
    worst_ratio: np.ndarray  # (trials,) max_t ||x(t)||_P e^{alpha t} / ||x(0)||_P under a random gamma(t) > zeta
    final_ratio: np.ndarray  # (trials,) ||x(T)||_P / ||x(0)||_P


def relaxed_projection_growth(A, B, P, *, trials: int = 200, T: float = 5.0, switch: float = 0.01,
                              max_factor: float = 100.0, seed: int = 0) -> RPGrowth:
    """Prop. 2.4.2 on xdot = A x + B u under (2.14): the P-decay rate at constant weights above zeta, and
    Monte Carlo trajectories with a piecewise-constant gamma(t) drawn log-uniformly in (1.01 zeta,
    max_factor zeta) every ``switch`` seconds, propagated exactly (matrix exponential per piece)."""
    A, B, P = (np.asarray(a, dtype=np.float64) for a in (A, B, P))
    B = B.reshape(A.shape[0], -1)
    zeta = smallest_zeta(A, B, P)
    alpha = -decay_rate(A, B, P, 1.01 * zeta)
    gammas = zeta * np.geomspace(1.01, max_factor, 25)
    rates = np.array([decay_rate(A, B, P, g) for g in gammas])
    rng = np.random.default_rng(seed)
    n = int(round(T / switch))
    pn = lambda x: float(np.sqrt(x @ P @ x))
    worst, final = np.empty(trials), np.empty(trials)
    for j in range(trials):
        x = rng.normal(size=A.shape[0])
        n0, w, t = pn(x), 0.0, 0.0
        for _ in range(n):
            g = zeta * np.exp(rng.uniform(np.log(1.01), np.log(max_factor)))
            x = sla.expm(rp_closed_loop(A, B, P, g) * switch) @ x
            t += switch
            w = max(w, pn(x) * np.exp(alpha * t) / n0)
        worst[j], final[j] = w, pn(x) / n0
    return RPGrowth(zeta, alpha, rates, gammas, worst, final)
