"""Subspace centered proximal point MHE, SCPX (thesis §1.5, (1.22)-(1.26), §1.6).

Only the p directions of largest eigenvalue of G^T G are fitted. With the SVD G = Ug S V^T (V = U_k of the
thesis, S^2 = Lambda_k), the weight of (1.22) is

    P_k = [G U_k  V_perp] diag(Sigma_k, 0) [...]^T,   Sigma_k = diag(lambda_1/lambda_1^2 .. lambda_p/lambda_p^2, 0..)

and since G u_i = s_i (Ug)_i, P_k = sum_{i<=p} (Ug)_i (Ug)_i^T: the orthogonal projector onto the p leading left
singular vectors. So psi_k(z) = 1/2 ||Ug_p^T (G z - q)||^2 (a constant apart), G^T P G = U diag(lambda_1..p, 0) U^T
= U Lambda~ U^T, and its proximal point is (1.26):

    p = U_p (Lambda~_p + I/gamma)^{-1} U_p^T (G^T q + xhat/gamma) + U_pc U_pc^T xhat,

computed in ``jaxdip.estimators.proximal.prox_from_svd`` with ``keep=p``. The thesis's §1.5.1 writes the
functional without the factor 1/2 of (1.22) but then solves it as if the 1/2 were there; (1.26), with the 1/2,
is what is implemented (SCPX with p = d is CPX exactly).
"""

from __future__ import annotations

from typing import Callable

from jaxdip.estimators.cpx import _lti_model, centered_component, centered_matrix, cpx_linearized
from jaxdip.estimators.linearized import lti_step
from jaxdip.estimators.proximal import prox_from_svd, svd_factor
from jaxdip.sim.component import Component


def scpx_lti(p: int, output: str = "prediction", from_truth: bool = False) -> Component:
    """SCPX for an LTI model ``params.model = Discrete(Phi, Phi_inv, W)``; the SVD of G is computed once."""

    def factor(params):
        m = params.model
        return svd_factor(centered_matrix(lti_step(m.Phi, m.Phi_inv, m.W), params.C))

    def solve(params, fac, G, q, xprior):
        return prox_from_svd(fac, q, xprior, params.gamma, p)

    return centered_component(_lti_model, factor, solve, output=output, from_truth=from_truth)


def scpx_linearized(f: Callable, h: float, n_inputs: int, p: int, output: str = "prediction",
                    from_truth: bool = False, svd: str = "jacobi", expm_squarings: int = 24) -> Component:
    """SCPX with the model relinearised at the prior centre estimate every step (thesis §1.6, p = 2 there)."""
    return cpx_linearized(f, h, n_inputs, keep=p, output=output, from_truth=from_truth, svd=svd,
                          expm_squarings=expm_squarings)
