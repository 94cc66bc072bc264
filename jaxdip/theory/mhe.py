"""Theory of the least-squares proximal point MHE (thesis Props 1.4.2, 1.4.3, 1.5.1, 1.5.2; paper Props 1-2).

Setting: x_{k+1} = Phi_k x_k + W_k u_k + eta_k, the fit phi_k(z) = 1/2 ||G_k((x_k + zeta_k) - z)||^2 with
zeta_k = (G_k^T G_k)^{-1} G_k^T v_k (v_k the noise vector of the window, ``jaxdip.estimators.proximal``), and the
observer p_k = Prox_{gamma_k phi_k}(xhat_k), xhat_{k+1} = Phi_k p_k + W_k u_k. With G^T G = U Lambda U^T:

* Prop 1.4.2: e_{k+1} = Phi_k U Lbar_k U^T e_k + Phi_k U Lddot_k U^T zeta_k - eta_k,  e_k = xhat_k - x_k,
  Lbar_ii = 1/(1 + gamma_k lambda_i),  Lddot_ii = gamma_k lambda_i/(1 + gamma_k lambda_i).
  (Inputs cancel: they enter xhat_{k+1} and x_{k+1} alike.)
* Prop 1.4.3: if gamma_k > gamma > max{(K_max - 1)/lambda_min, 0}, then ||e_{k+1}|| <= r ||e_k|| + kappa with
  r = K_max/(1 + gamma lambda_min) < 1, kappa = K_max zeta_bar + eta_bar, hence
  ||e_k|| <= r^k ||e_0|| + kappa (1 - r^k)/(1 - r) and limsup ||e_k|| <= kappa/(1 - r).
* Prop 1.5.1 / 1.5.2 (subspace, p kept directions): e_{k+1} = Phi U_p Lbar_p U_p^T e + Phi U_pc U_pc^T e
  + Phi U_p Lddot_p U_p^T zeta - eta; with ||Phi_k U_pc U_pc^T|| < alpha < 1 and
  gamma > max{(K_max - (1 - alpha))/(lambda_p,min (1 - alpha)), 0}: r = K_max/(1 + gamma lambda_p,min) + alpha,
  same kappa and bound.

K_max bounds the spectral norms ||Phi_k|| (Lipschitz constants of the linear maps).
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp


def eig_gram(G):
    """(lambda descending, U) with G^T G = U diag(lambda) U^T, from the SVD of G (no G^T G formed)."""
    l, d = G.shape
    _, s, Vt = jnp.linalg.svd(G, full_matrices=l < d)
    if l < d:
        s = jnp.concatenate([s, jnp.zeros(d - l, G.dtype)])
    return s**2, Vt.T


def discrepancy(G, v):
    """zeta = (G^T G)^{-1} G^T v, the least-squares solution of G zeta = v."""
    return jnp.linalg.lstsq(G, v)[0]


def horizon_noise(Phis, Cs, etas, epss):
    """The noise vector v_k of a window (thesis, below (1.18)).

    Phis (N, d, d) = Phi_k..Phi_{k+N-1}; Cs (N, p, d) = C_{k+1}..C_{k+N}; etas (N, d) = eta_k..eta_{k+N-1};
    epss (N, p) = eps_{k+1}..eps_{k+N}. Row block i: C_{k+i} sum_{j<i} Phi_{k+i-1}..Phi_{k+j+1} eta_{k+j} + eps_{k+i}.
    """

    def body(acc, inp):
        Phi, C, eta, eps = inp
        acc = Phi @ acc + eta
        return acc, C @ acc + eps

    _, v = jax.lax.scan(body, jnp.zeros(Phis.shape[-1], Phis.dtype), (Phis, Cs, etas, epss))
    return v.reshape(-1)


def error_step(Phi, G, gamma, e, zeta, eta, keep: Optional[int] = None):
    """One step of the error recursion of Prop 1.4.2 (or Prop 1.5.1 with ``keep`` = p)."""
    lam, U = eig_gram(G)
    gl = gamma * lam
    lbar = 1.0 / (1.0 + gl)
    lddot = gl / (1.0 + gl)
    if keep is not None:
        kept = jnp.arange(lam.shape[0]) < keep
        lbar = jnp.where(kept, lbar, 1.0)  # U_pc U_pc^T e passes unchanged
        lddot = jnp.where(kept, lddot, 0.0)  # zeta has no effect outside the kept directions
    return Phi @ (U @ (lbar * (U.T @ e)) + U @ (lddot * (U.T @ zeta))) - eta


def error_recursion(Phis, Gs, gammas, e0, zetas, etas, keep: Optional[int] = None):
    """e_0 .. e_K from Prop 1.4.2 (1.5.1): Phis (K, d, d), Gs (K, l, d), gammas (K,), zetas/etas (K, d)."""
    gammas = jnp.broadcast_to(jnp.asarray(gammas, Phis.dtype), (Phis.shape[0],))

    def body(e, inp):
        Phi, G, g, z, eta = inp
        e = error_step(Phi, G, g, e, z, eta, keep)
        return e, e

    _, es = jax.lax.scan(body, jnp.asarray(e0, Phis.dtype), (Phis, Gs, gammas, zetas, etas))
    return jnp.concatenate([jnp.asarray(e0, Phis.dtype)[None], es])


# ---- fixed-gamma criteria and bounds ----------------------------------------------------------------------


class Bound(NamedTuple):
    gamma_min: jnp.ndarray  # the criterion: gamma must exceed this
    r: jnp.ndarray  # contraction factor at the given gamma
    kappa: jnp.ndarray
    limit: jnp.ndarray  # kappa / (1 - r) (inf when r >= 1)


def gamma_criterion(K_max, lam_min):
    """Prop 1.4.3: gamma > max{(K_max - 1)/lambda_min, 0}."""
    return jnp.maximum((K_max - 1.0) / lam_min, 0.0)


def gamma_criterion_subspace(K_max, lam_p_min, alpha):
    """Prop 1.5.2: gamma > max{(K_max - (1 - alpha))/(lambda_p,min (1 - alpha)), 0}."""
    return jnp.maximum((K_max - (1.0 - alpha)) / (lam_p_min * (1.0 - alpha)), 0.0)


def _limit(r, kappa):
    return jnp.where(r < 1.0, kappa / jnp.where(r < 1.0, 1.0 - r, 1.0), jnp.inf)


def error_bound(gamma, K_max, lam_min, zeta_bar, eta_bar) -> Bound:
    """Prop 1.4.3: r = K/(1 + gamma lambda_min), kappa = K zeta_bar + eta_bar, limit kappa/(1 - r)."""
    r = K_max / (1.0 + gamma * lam_min)
    kappa = K_max * zeta_bar + eta_bar
    return Bound(gamma_criterion(K_max, lam_min), r, kappa, _limit(r, kappa))


def error_bound_subspace(gamma, K_max, lam_p_min, alpha, zeta_bar, eta_bar) -> Bound:
    """Prop 1.5.2: r = K/(1 + gamma lambda_p,min) + alpha, kappa = K zeta_bar + eta_bar."""
    r = K_max / (1.0 + gamma * lam_p_min) + alpha
    kappa = K_max * zeta_bar + eta_bar
    return Bound(gamma_criterion_subspace(K_max, lam_p_min, alpha), r, kappa, _limit(r, kappa))


def finite_time_bound(e0_norm, r, kappa, k):
    """||e_k|| <= r^k ||e_0|| + kappa sum_{m<k} r^m (the inequality behind Props 1.4.3 and 1.5.2)."""
    k = jnp.asarray(k)
    geom = jnp.where(jnp.abs(1.0 - r) > 1e-15, (1.0 - r**k) / jnp.where(jnp.abs(1.0 - r) > 1e-15, 1.0 - r, 1.0), k)
    return r**k * e0_norm + kappa * geom


def lti_gamma_criterion(Phi, G):
    """Prop 1.4.3 for a fixed model: (||Phi||_2 - 1)/lambda_min(G^T G), clipped at 0; returns (gamma, K, lam_min)."""
    K = jnp.linalg.norm(Phi, 2)
    lam_min = eig_gram(G)[0][-1]
    return gamma_criterion(K, lam_min), K, lam_min


def subspace_alpha(Phi, G, p: int):
    """||Phi U_pc U_pc^T||_2: the part of the error the subspace estimator cannot correct (Prop 1.5.2's alpha)."""
    _, U = eig_gram(G)
    Upc = U[:, p:]
    return jnp.linalg.norm(Phi @ Upc @ Upc.T, 2)


def cpx_gamma_criterion(Phi, Phi_inv, C):
    """Prop 1.4.3 for the centred functional (1.29): G = [C Phi^{-1}; C; C Phi]."""
    G = jnp.concatenate([C @ Phi_inv, C, C @ Phi], axis=0)
    return lti_gamma_criterion(Phi, G)


def centered_noise(Phi_inv, C, eta_prev, eps_prev, eps_mid, eta, eps_next):
    """v_k of the centred functional (thesis (1.30)):
    [-C Phi^{-1} eta_{k-1} + eps_{k-1};  eps_k;  C eta_k + eps_{k+1}]."""
    return jnp.concatenate([-C @ (Phi_inv @ eta_prev) + eps_prev, eps_mid, C @ eta + eps_next])
