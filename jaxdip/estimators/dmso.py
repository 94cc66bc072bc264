"""Discrete modified state observer (DMSO) of Stumfoll, eqs. (1)-(6) and (172)-(175).

Model with an unknown uncertainty in the rows selected by B (n x p, zeros and ones, B^T B = I):

    (1)  x_{k+1} = F x_k + G u_k + B f(x_k),          y_k = x_k (+ sensor errors)            (2)

Observer, network and weight update, as decided from the (partly mangled) text:

    (3)  xhat_{k+1} = F xhat_k + G u_k + B fhat_k + K (y_k - xhat_k)
    (4)  fhat_k     = W_k^T phi(y_k)                           W: l x p, phi: R^n -> R^l
    (6)  W_{k+1}    = W_k + Gamma phi(y_k) e_{k+1}^T B,   e_{k+1} = y_{k+1} - xhat_{k+1}

* phi is evaluated at the *measurement* y_k. The thesis writes phi(x_k) with y_k = x_k (2); with sensor errors
  the observer has only y_k (docs/models.md: full-state measurements, e_{k+1} = y_{k+1} - xhat_{k+1}).
* (6) as printed, phi(x_k) e_{k+1}^T B_MSO, is l x 1 times 1 x n times n x p = l x p, the shape of W: no
  transpose is missing. Gamma is a scalar in the thesis; an l x l matrix is accepted too (Gamma @ phi).
* The basis (§8.1.1) is phi(x) = [1, tansig(x_1), ..., tansig(x_n)] with tansig = tanh. Its "differentiable
  hyperparameters" here are an input scale and offset, phi_i = tanh(s_i x_i + c_i) (s = 1, c = 0: the thesis).
* The update of W needs y_{k+1}, so it happens one sample late: the observer's state carries xhat_k, W_k and
  y_k, and when y_{k+1} arrives it forms xhat_{k+1} by (3) with the carried quantities, then e_{k+1} and
  W_{k+1} by (6). Carrying y_k (rather than phi(y_k)) lets phi be recomputed once per sample with the current
  basis parameters.

In the loop sample k brings (y_k, u_{k-1}) and the estimator hands the controller
xhat_k. For k >= 1 that is (3) advanced from k - 1 with u_{k-1}: the DMSO is a one-step *predictor*; its
estimate of x_k uses y_0 .. y_{k-1}, not y_k. At k = 0 it returns xhat_0 (the thesis starts it at zero) and
W_0 (zeros). The KF compared with it in the thesis, (169)-(170) with y_k in the update of x_{k+1}, is a
predictor on the same information; see ``experiments.twip_dmso`` for how the KF is read.

With Gamma = 0 and f = 0 the error obeys e_{k+1} = (F - K) e_k (11): a Luenberger observer in prediction form.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.roles import Estimator, param


from jaxdip._public import public_dir

# not listed: predict (jaxdip.estimators.kalman.predict is the one public predict; DMSO.step is the route here)
__all__ = ["DMSOState", "tanh_basis", "selection_matrix", "update_weights", "advance", "DMSOAux", "DMSO"]
__dir__ = public_dir(globals())


class DMSOState(NamedTuple):
    xhat: jnp.ndarray  # xhat_k
    W: jnp.ndarray  # W_k (already updated with e_k)
    y: jnp.ndarray  # y_k, kept for the next prediction and weight update


def tanh_basis(params, x):
    """phi(x) = [1, tanh(s_1 x_1 + c_1), ..., tanh(s_n x_n + c_n)] (§8.1.1, with s = 1, c = 0)."""
    z = jnp.tanh(params.basis_scale * x + params.basis_offset)
    return jnp.concatenate([jnp.ones((1,), z.dtype), z])


def selection_matrix(n: int, rows) -> jnp.ndarray:
    """B_MSO: the n x p matrix with a one in row ``rows[j]`` of column j (173: rows (1, 3) of 4, 0-based)."""
    B = jnp.zeros((n, len(rows)))
    return B.at[jnp.asarray(rows), jnp.arange(len(rows))].set(1.0)


def _gamma_phi(Gamma, phi):
    return Gamma @ phi if jnp.ndim(Gamma) == 2 else Gamma * phi


def predict(params, basis: Callable, xhat, W, y, u):
    """(3)-(4): xhat_{k+1} from xhat_k, W_k, y_k, u_k; also returns fhat_k and phi(y_k)."""
    phi = basis(params, y)
    fhat = W.T @ phi
    xnext = params.F @ xhat + params.G @ u + params.B @ fhat + params.K @ (y - xhat)
    return xnext, fhat, phi


def update_weights(params, W, phi, e_next):
    """(6): W_{k+1} = W_k + Gamma phi(y_k) e_{k+1}^T B."""
    return W + jnp.outer(_gamma_phi(params.Gamma, phi), params.B.T @ e_next)


def advance(params, basis: Callable, st: DMSOState, y_next, u):
    """One sample: from (xhat_k, W_k, y_k) and u_k, y_{k+1} to (xhat_{k+1}, W_{k+1}, y_{k+1}); returns fhat_k."""
    xnext, fhat, phi = predict(params, basis, st.xhat, st.W, st.y, u)
    W = update_weights(params, st.W, phi, y_next - xnext)
    return DMSOState(xnext, W, y_next), fhat


class DMSOAux(NamedTuple):
    fhat: jnp.ndarray  # fhat_{k-1} = W_{k-1}^T phi(y_{k-1}), used to predict xhat_k (zeros at k = 0)
    W: jnp.ndarray  # W_k, the weights after this sample's update


class DMSO(Estimator):
    """The DMSO as an engine estimator: the model, gains and basis parameters are its array fields, the basis
    is static (``tanh_basis``). Sample k brings (y_k, u_{k-1}); the output is xhat_k (module doc). ``aux`` is a
    ``DMSOAux``: the network's estimate fhat_{k-1} of the uncertainty and the weights W_k, so a run records
    them with ``save`` and a run over recorded data (``jaxdip.estimators.recorded.run``) returns them.
    ``DMSO.thesis(F, G, B, ...)`` builds it with the thesis's defaults."""

    F: jax.Array = param()
    G: jax.Array = param()
    B: jax.Array = param()
    K: jax.Array = param()
    Gamma: jax.Array = param()
    basis_scale: jax.Array = param()
    basis_offset: jax.Array = param()
    W0: jax.Array = param()
    xhat0: jax.Array = param()
    basis: Callable = eqx.field(default=tanh_basis, static=True)

    @classmethod
    def thesis(cls, F, G, B, K=None, Gamma=0.1, basis_scale=None, basis_offset=None, W0=None, xhat0=None,
               n_basis: int | None = None, basis: Callable = tanh_basis) -> "DMSO":
        """The thesis's defaults: K = I (174), Gamma = 0.1 (175), W0 = 0, xhat0 = 0. ``n_basis`` is l, the
        length of phi (n + 1 for ``tanh_basis``)."""
        f64 = lambda a: jnp.asarray(a, dtype=jnp.float64)  # noqa: E731
        F, G, B = f64(F), f64(G), f64(B)
        n = F.shape[0]
        G = G.reshape(n, -1)
        B = B.reshape(n, -1)
        l = n + 1 if n_basis is None else n_basis
        K = jnp.eye(n) if K is None else f64(K)
        if K.ndim == 1:
            K = jnp.diag(K)
        return cls(F=F, G=G, B=B, K=K, Gamma=f64(Gamma),
                   basis_scale=jnp.ones(n) if basis_scale is None else f64(basis_scale),
                   basis_offset=jnp.zeros(n) if basis_offset is None else f64(basis_offset),
                   W0=jnp.zeros((l, B.shape[1])) if W0 is None else f64(W0),
                   xhat0=jnp.zeros(n) if xhat0 is None else f64(xhat0), basis=basis)

    def __check_init__(self):
        n = checks.check_square(self, "F", self.F)
        why = f"for an {n}-state model (F is {checks.fmt_shape(self.F.shape)})"
        checks.check_shape(self, "G", self.G, (n, None), why)
        checks.check_shape(self, "B", self.B, (n, None), why)
        checks.check_shape(self, "K", self.K, (n, n), why)
        checks.check_shape(self, "W0", self.W0, (None, self.B.shape[1]), f"(B is {checks.fmt_shape(self.B.shape)})")
        checks.check_state_vector(self, "xhat0", self.xhat0, n, why)
        for name in ("F", "G", "B", "K", "W0", "basis_scale", "basis_offset"):
            checks.check_finite(self, name, getattr(self, name))
        checks.check_nonnegative(self, "Gamma", self.Gamma)

    def io_sizes(self) -> dict:
        shape = checks.fmt_shape
        return {"out": (self.F.shape[0], f"F is {shape(self.F.shape)}"),
                "u": (self.G.shape[1], f"G is {shape(self.G.shape)}")}

    def init(self, key, x0):
        xhat0 = jnp.asarray(self.xhat0, dtype=jnp.float64)
        return DMSOState(xhat0, jnp.asarray(self.W0, dtype=jnp.float64), xhat0)

    def step(self, state, y, u_prev, key, k):
        y = jnp.asarray(y, dtype=state.xhat.dtype)
        u_prev = jnp.reshape(jnp.asarray(u_prev, state.xhat.dtype), (self.G.shape[1],))
        nxt, fhat = advance(self, self.basis, state, y, u_prev)
        first = k == 0
        new = DMSOState(xhat=jnp.where(first, state.xhat, nxt.xhat), W=jnp.where(first, state.W, nxt.W), y=y)
        return new, new.xhat, DMSOAux(jnp.where(first, jnp.zeros_like(fhat), fhat), new.W)
