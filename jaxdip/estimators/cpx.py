"""Centered proximal point MHE, CPX (paper eq. (6), thesis (1.29)-(1.30), §3.3 (3.7)-(3.8)).

The window holds the three most recent outputs and is centred on the middle one. With the discrete model
x_{k+1} = Phi x_k + W u_k + b (b = 0 for an LTI model, the linearisation offset otherwise, see
``jaxdip.estimators.linearized``) the functional fitted around the centre state z = x_k is

    phi_k(z) = 1/2 ||C z_{k-1} - y_{k-1}||^2 + 1/2 ||C z - y_k||^2 + 1/2 ||C z_{k+1} - y_{k+1}||^2
    z_{k+1} = Phi z + W u_k + b,     z_{k-1} = Phi^{-1} (z - W u_{k-1} - b),

i.e. 1/2 ||G z - q_k||^2 with

    G   = [C Phi^{-1}; C; C Phi],
    q_k = [y_{k-1} + C Phi^{-1} (W u_{k-1} + b);  y_k;  y_{k+1} - C (W u_k + b)].

The backward input term is derived, not copied: the documents print it as C W^{-1} B u, which has no meaning
for a column W; from x_k = Phi x_{k-1} + W u_{k-1} follows C x_{k-1} = C Phi^{-1} x_k - C Phi^{-1} W u_{k-1}
(docs/models.md).

Timing: at sample j the estimator receives y_j and u_{j-1}; the window is
(y_{j-2}, y_{j-1}, y_j) and its centre is x_{j-1}. One step is

    p_{j-1}  = Prox_{gamma phi}(xhat_{j-1})
    xhat_j   = Phi p_{j-1} + W u_{j-1} + b                       (thesis (3.8))
    xtilde_{j+1} = Phi xhat_j + W u_{j-1} + b                     (the estimate handed to a controller)

The documents write the last line with u_{j} (u_{k+1} in their indexing), which is the control that is about
to be computed from this very estimate; the input last applied is held instead. The output is xhat_j; ``aux`` is
a ``CPXAux`` (xhat_j and xtilde_{j+1}), and ``Ahead(cpx)`` (``jaxdip.estimators.wrappers``) hands out
xtilde_{j+1}. For j = 0 the estimate is xhat_0; for j = 1 (two outputs only) the model propagates xhat_0.

Two estimators:

* ``CPX``: LTI model; the thesis's (3.7)-(3.8): H = [I/sqrt(gamma); G] factorised once (in ``init``, so the
  factorisation is a differentiable function of gamma), then p = R^{-1} Q^T [xhat/sqrt(gamma); q] by a
  triangular solve at every step. The thesis prints the top block as I/gamma; with it the minimiser is the
  proximal point of gamma^2, not gamma. I/sqrt(gamma) is what makes (3.7) the step (1.10) that Props 1.4.2-1.4.3
  analyse (and the DIP's gamma = 150 "two orders of magnitude" below the criterion 24400 only reads right in
  this scaling). With ``keep=p`` it is the subspace estimator SCPX, the SVD of G computed once instead.
* ``LinearizedCPX``: a nonlinear model linearised at the prior centre estimate at every step (§1.6), Phi and
  Phi^{-1} by the matrix exponential over h, the proximal step by the SVD of G; ``keep=p`` gives SCPX.

SCPX (thesis §1.5, (1.22)-(1.26), §1.6) fits only the p directions of largest eigenvalue of G^T G. With the SVD
G = Ug S V^T (V = U_k of the thesis, S^2 = Lambda_k), the weight of (1.22) is P_k = sum_{i<=p} (Ug)_i (Ug)_i^T,
the orthogonal projector onto the p leading left singular vectors. So psi_k(z) = 1/2 ||Ug_p^T (G z - q)||^2 (a
constant apart), G^T P G = U diag(lambda_1..p, 0) U^T, and its proximal point is (1.26):

    p = U_p (Lambda~_p + I/gamma)^{-1} U_p^T (G^T q + xhat/gamma) + U_pc U_pc^T xhat,

computed by ``jaxdip.estimators.proximal.prox_from_svd`` with ``keep=p``. The thesis's §1.5.1 writes the
functional without the factor 1/2 of (1.22) but then solves it as if the 1/2 were there; (1.26), with the 1/2,
is what is implemented (SCPX with p = d is CPX exactly).
"""

from __future__ import annotations

from typing import Any, NamedTuple, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, Plant, param, dtype_of, rhs
from jaxdip.estimators.linearized import AffineStep, local_model, lti_step
from jaxdip.estimators.proximal import prox_from_qr, prox_from_svd, qr_factor, svd_factor
from jaxdip.sim.discretize import Discrete


from jaxdip._public import public_dir

__all__ = ["centered_matrix", "centered_vector", "CPXState", "CPXAux", "CPX", "LinearizedCPX"]
__dir__ = public_dir(globals())


def centered_matrix(step: AffineStep, C):
    """G = [C Phi^{-1}; C; C Phi] (thesis (1.30))."""
    return jnp.concatenate([C @ step.Phi_inv, C, C @ step.Phi], axis=0)


def centered_vector(step: AffineStep, C, y_prev, y_mid, y_next, u_back, u_fwd):
    """q_k = [y_{k-1} + C Phi^{-1}(W u_{k-1} + b); y_k; y_{k+1} - C (W u_k + b)]."""
    back = y_prev + C @ (step.Phi_inv @ (step.W @ u_back + step.b))
    fwd = y_next - C @ (step.W @ u_fwd + step.b)
    return jnp.concatenate([back, y_mid, fwd])


class CPXState(NamedTuple):
    factor: Any  # offline factorisation (CPX: (Q^T, R), or the SVD of G with keep) or ()
    xc: jnp.ndarray  # prior estimate of the next window's centre state
    y_m2: jnp.ndarray  # y_{j-2} (after the step: y_{j-1})
    y_m1: jnp.ndarray  # y_{j-1}
    u_m2: jnp.ndarray  # u_{j-2}


class CPXAux(NamedTuple):
    xhat: jax.Array  # xhat_j, the current estimate (the output)
    ahead: jax.Array  # xtilde_{j+1} = Phi xhat_j + W u_{j-1} + b, the prediction with the input held


def _lti_sizes(Phi, W, C, prefix: str = "") -> dict:
    shape = checks.fmt_shape
    return {"in": (C.shape[0], f"C is {shape(C.shape)}"), "out": (Phi.shape[0], f"{prefix}Phi is {shape(Phi.shape)}"),
            "u": (W.shape[1], f"{prefix}W is {shape(W.shape)}")}


class _Centred(Estimator):
    """The step shared by the centred estimators: subclasses give ``_model(xbar, ubar) -> AffineStep``,
    ``_factor()`` (the offline factor, or ()), ``_solve(factor, G, q, xprior)`` and ``n_inputs``."""

    def init(self, key, x0):
        x_init = jnp.asarray(self.xhat0, dtype=dtype_of(x0))
        z = jnp.zeros(self.C.shape[0], x_init.dtype)
        return CPXState(self._factor(), x_init, z, z, jnp.zeros(self.n_inputs, x_init.dtype))

    def step(self, state, y, u_prev, key, k):
        st = state
        u_prev = jnp.reshape(jnp.asarray(u_prev, st.xc.dtype), st.u_m2.shape)
        model = self._model(st.xc, u_prev)
        G = centered_matrix(model, self.C)
        q = centered_vector(model, self.C, st.y_m2, st.y_m1, y, st.u_m2, u_prev)
        p = jnp.where(k >= 2, self._solve(st.factor, G, q, st.xc), st.xc)
        xhat = jnp.where(k == 0, st.xc, model.Phi @ p + model.W @ u_prev + model.b)
        ahead = model.Phi @ xhat + model.W @ u_prev + model.b
        return CPXState(st.factor, xhat, st.y_m1, y, u_prev), xhat, CPXAux(xhat, ahead)


class CPX(_Centred):
    """CPX for an LTI model ``model = Discrete(Phi, Phi_inv, W)``: offline QR, triangular solves online; SCPX
    with ``keep=p`` (offline SVD). ``gamma`` is a traced leaf (the factor is computed from it in ``init``, so
    gradients and sweeps over gamma need no recompilation)."""

    gamma: jax.Array = param()
    model: Discrete = eqx.field(converter=lambda m: Discrete(*(jnp.asarray(a, jnp.result_type(float)) for a in m)))
    C: jax.Array = param()
    xhat0: jax.Array = param()
    keep: Optional[int] = eqx.field(default=None, static=True)

    def __check_init__(self):
        d, _, _ = checks.check_lti(self, self.model.Phi, self.model.W, self.C, self.model.Phi_inv, prefix="model.")
        checks.check_state_vector(self, "xhat0", self.xhat0, d, f"for a {d}-state model")
        checks.check_ndim(self, "gamma", self.gamma, (0,), "a scalar")
        checks.check_positive(self, "gamma", self.gamma)
        if self.keep is not None:
            checks.check_int(self, "keep", self.keep, 1)

    def io_sizes(self) -> dict:
        return _lti_sizes(self.model.Phi, self.model.W, self.C, "model.")

    @property
    def n_inputs(self) -> int:
        return self.model.W.shape[1]

    def _model(self, xbar, ubar):
        return lti_step(self.model.Phi, self.model.Phi_inv, self.model.W)

    def _factor(self):
        G = centered_matrix(self._model(None, None), self.C)
        return qr_factor(G, self.gamma) if self.keep is None else svd_factor(G)

    def _solve(self, factor, G, q, xprior):
        if self.keep is None:
            QT, R = factor
            return prox_from_qr(QT, R, q, xprior, self.gamma)
        return prox_from_svd(factor, q, xprior, self.gamma, self.keep)


class LinearizedCPX(_Centred):
    """CPX relinearised at the prior centre estimate every sample (thesis §1.6), or SCPX with ``keep=p``.

    ``model`` is an engine ``Plant`` (its ``vector_field`` is linearised; its parameters are traced leaves);
    ``h`` is the sample period. ``svd``: "jacobi" (vectorises under vmap) or "lapack"; ``expm_squarings``: see
    ``linearized.expm_small``."""

    gamma: jax.Array = param()
    model: Any
    C: jax.Array = param()
    xhat0: jax.Array = param()
    h: float = eqx.field(static=True)
    keep: Optional[int] = eqx.field(default=None, static=True)
    svd: str = eqx.field(default="jacobi", static=True)
    expm_squarings: int = eqx.field(default=24, static=True)

    def __check_init__(self):
        if not isinstance(self.model, Plant):
            raise checks.ArgumentTypeError(f"LinearizedCPX: model must be a jaxdip Plant, got {type(self.model).__name__}")
        d = self.model.n
        why = f"for the {d}-state model {type(self.model).__name__}"
        checks.check_shape(self, "C", self.C, (None, d), why)
        checks.check_finite(self, "C", self.C)
        checks.check_state_vector(self, "xhat0", self.xhat0, d, why)
        checks.check_ndim(self, "gamma", self.gamma, (0,), "a scalar")
        checks.check_positive(self, "gamma", self.gamma)
        checks.check_positive(self, "h", self.h)
        checks.check_choice(self, "svd", self.svd, ("jacobi", "lapack"))
        if self.keep is not None:
            checks.check_int(self, "keep", self.keep, 1)

    def io_sizes(self) -> dict:
        why = f"C is {checks.fmt_shape(self.C.shape)}"
        return {"in": (self.C.shape[0], why), "out": (self.model.n, f"model has {self.model.n} states"),
                "u": (self.model.m, f"model has {self.model.m} inputs")}

    @property
    def n_inputs(self) -> int:
        return self.model.m

    def _model(self, xbar, ubar):
        return local_model(rhs, self.model, xbar, ubar, self.h, max_squarings=self.expm_squarings)

    def _factor(self):
        return ()

    def _solve(self, factor, G, q, xprior):
        return prox_from_svd(svd_factor(G, self.svd), q, xprior, self.gamma, self.keep)
