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

Timing in the init/step interface: at sample j the component receives y_j and u_{j-1}; the window is
(y_{j-2}, y_{j-1}, y_j) and its centre is x_{j-1}. One step is

    p_{j-1}  = Prox_{gamma phi}(xhat_{j-1})
    xhat_j   = Phi p_{j-1} + W u_{j-1} + b                       (thesis (3.8))
    xtilde_{j+1} = Phi xhat_j + W u_{j-1} + b                     (the estimate handed to a controller)

The documents write the last line with u_{j} (u_{k+1} in their indexing), which is the control that is about
to be computed from this very estimate; the input last applied is held instead. ``output="current"`` returns
xhat_j. For j = 0 the estimate is xhat_0; for j = 1 (two outputs only) the model propagates xhat_0.

Two implementations:

* ``cpx_qr``: LTI model; the thesis's (3.7)-(3.8): H = [I/sqrt(gamma); G] factorised once (in ``init``, so the
  factorisation is a differentiable function of gamma), then p = R^{-1} Q^T [xhat/sqrt(gamma); q] by a
  triangular solve at every step. The thesis prints the top block as I/gamma; with it the minimiser is the
  proximal point of gamma^2, not gamma. I/sqrt(gamma) is what makes (3.7) the step (1.10) that Props 1.4.2-1.4.3
  analyse (and the DIP's gamma = 150 "two orders of magnitude" below the criterion 24400 only reads right in
  this scaling).
* ``cpx_linearized``: a nonlinear model linearised at the prior centre estimate at every step (§1.6), Phi and
  Phi^{-1} by the matrix exponential over h, the proximal step by the SVD of G. ``keep=p`` gives the subspace
  estimator SCPX (``jaxdip.estimators.scpx``).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine.roles import Estimator, param
from jaxdip.estimators.linearized import AffineStep, local_model, lti_step
from jaxdip.estimators.proximal import prox_from_qr, prox_from_svd, qr_factor, svd_factor
from jaxdip.sim.component import Component
from jaxdip.sim.discretize import Discrete


def centered_matrix(step: AffineStep, C):
    """G = [C Phi^{-1}; C; C Phi] (thesis (1.30))."""
    return jnp.concatenate([C @ step.Phi_inv, C, C @ step.Phi], axis=0)


def centered_vector(step: AffineStep, C, y_prev, y_mid, y_next, u_back, u_fwd):
    """q_k = [y_{k-1} + C Phi^{-1}(W u_{k-1} + b); y_k; y_{k+1} - C (W u_k + b)]."""
    back = y_prev + C @ (step.Phi_inv @ (step.W @ u_back + step.b))
    fwd = y_next - C @ (step.W @ u_fwd + step.b)
    return jnp.concatenate([back, y_mid, fwd])


class CPXParams(NamedTuple):
    gamma: Any  # proximal weight
    model: Any  # Discrete(Phi, Phi_inv, W) for cpx_qr; the plant's parameter pytree for cpx_linearized
    C: jnp.ndarray  # (p, d) output matrix
    xhat0: jnp.ndarray  # (d,) initial estimate (ignored with from_truth=True)


class CPXState(NamedTuple):
    factor: Any  # offline factorisation (cpx_qr: (Q^T, R); scpx_lti: SVDFactor) or ()
    xc: jnp.ndarray  # prior estimate of the next window's centre state
    y_m2: jnp.ndarray  # y_{j-2} (after the step: y_{j-1})
    y_m1: jnp.ndarray  # y_{j-1}
    u_m2: jnp.ndarray  # u_{j-2}


def centered_component(model_fn: Callable, factor_fn: Callable, solve_fn: Callable, n_inputs: Optional[int] = None,
                       output: str = "prediction", from_truth: bool = False) -> Component:
    """The step shared by every centred estimator.

    model_fn(params, xbar, ubar) -> AffineStep;  factor_fn(params) -> offline factor (or ());
    solve_fn(params, factor, G, q, xprior) -> proximal point.
    """
    if output not in ("current", "prediction"):
        raise ValueError(f"output must be 'current' or 'prediction', got {output!r}")

    def init(params, key, x0):
        x_init = jnp.asarray(x0 if from_truth else params.xhat0, dtype=jnp.result_type(float))
        p_dim = params.C.shape[0]
        m = n_inputs if n_inputs is not None else params.model.W.shape[1]
        z = jnp.zeros(p_dim, x_init.dtype)
        return CPXState(factor_fn(params), x_init, z, z, jnp.zeros(m, x_init.dtype))

    def step(params, st: CPXState, inp, key, k):
        y, u_prev = inp
        u_prev = jnp.reshape(jnp.asarray(u_prev, st.xc.dtype), st.u_m2.shape)
        model = model_fn(params, st.xc, u_prev)
        G = centered_matrix(model, params.C)
        q = centered_vector(model, params.C, st.y_m2, st.y_m1, y, st.u_m2, u_prev)
        p = jnp.where(k >= 2, solve_fn(params, st.factor, G, q, st.xc), st.xc)
        xhat = jnp.where(k == 0, st.xc, model.Phi @ p + model.W @ u_prev + model.b)
        out = xhat if output == "current" else model.Phi @ xhat + model.W @ u_prev + model.b
        return CPXState(st.factor, xhat, st.y_m1, y, u_prev), out

    return Component(init, step)


def _lti_model(params, xbar, ubar):
    m: Discrete = params.model
    return lti_step(m.Phi, m.Phi_inv, m.W)


def cpx_qr(output: str = "prediction", from_truth: bool = False) -> Component:
    """CPX for an LTI model ``params.model = Discrete(Phi, Phi_inv, W)``: offline QR, triangular solves online."""

    def factor(params):
        m = params.model
        return qr_factor(centered_matrix(lti_step(m.Phi, m.Phi_inv, m.W), params.C), params.gamma)

    def solve(params, fac, G, q, xprior):
        QT, R = fac
        return prox_from_qr(QT, R, q, xprior, params.gamma)

    return centered_component(_lti_model, factor, solve, output=output, from_truth=from_truth)


def cpx_linearized(f: Callable, h: float, n_inputs: int, keep: Optional[int] = None, output: str = "prediction",
                   from_truth: bool = False, svd: str = "jacobi", expm_squarings: int = 24) -> Component:
    """CPX (or SCPX with ``keep=p``) for continuous dynamics ``f(model_params, x, u)`` relinearised every step.

    ``h`` is the sample period (static). ``params.model`` is the plant's parameter pytree. ``svd``: "jacobi"
    (vectorises under vmap) or "lapack"; ``expm_squarings``: see ``linearized.expm_small``.
    """

    def model_fn(params, xbar, ubar):
        return local_model(f, params.model, xbar, ubar, h, max_squarings=expm_squarings)

    def solve(params, fac, G, q, xprior):
        return prox_from_svd(svd_factor(G, svd), q, xprior, params.gamma, keep)

    return centered_component(model_fn, lambda params: (), solve, n_inputs=n_inputs, output=output,
                              from_truth=from_truth)


class CPX(Estimator):
    """CPX for an LTI model as an engine estimator (the ``cpx_qr`` estimator with its params as fields).

    ``model`` is ``Discrete(Phi, Phi_inv, W)``; ``gamma`` is a traced leaf (the QR factor of H is computed from
    it in ``init``, so gradients and sweeps over gamma need no recompilation). ``aux`` is the current estimate
    xhat_j (the output is the prediction unless ``output="current"``)."""

    gamma: jax.Array = param()
    model: Discrete = eqx.field(converter=lambda m: Discrete(*(jnp.asarray(a, jnp.result_type(float)) for a in m)))
    C: jax.Array = param()
    xhat0: jax.Array = param()
    output: str = eqx.field(default="prediction", static=True)
    from_truth: bool = eqx.field(default=False, static=True)

    def __check_init__(self):
        if self.output not in ("current", "prediction"):
            raise ValueError(f"output must be 'current' or 'prediction', got {self.output!r}")

    def _component(self) -> Component:
        # the module has CPXParams' field names, so it is the params of the shared centred step
        return cpx_qr(self.output, self.from_truth)

    def init(self, key, x0):
        return self._component().init(self, key, x0)

    def step(self, state, y, u_prev, key, k):
        state, out = self._component().step(self, state, (y, u_prev), key, k)
        return state, out, state.xc


def _plant_vector_field(plant, x, u):
    # module-level, so every LinearizedCPX of one structure traces the same function
    return plant.vector_field(x, u)


class LinearizedCPX(Estimator):
    """CPX relinearised at the prior centre estimate every sample (thesis §1.6), or SCPX with ``keep=p``: the
    ``cpx_linearized`` estimator with its params as fields.

    ``model`` is an engine ``Plant`` (its ``vector_field`` is linearised; its parameters are traced leaves);
    ``h`` is the sample period. ``aux`` is the current estimate xhat_j (the output is the prediction unless
    ``output="current"``). Numbers identical to ``cpx_linearized(plant.f, ...)`` with the plant's params."""

    gamma: jax.Array = param()
    model: Any
    C: jax.Array = param()
    xhat0: jax.Array = param()
    h: float = eqx.field(static=True)
    keep: Optional[int] = eqx.field(default=None, static=True)
    output: str = eqx.field(default="prediction", static=True)
    from_truth: bool = eqx.field(default=False, static=True)
    svd: str = eqx.field(default="jacobi", static=True)
    expm_squarings: int = eqx.field(default=24, static=True)

    def __check_init__(self):
        if self.output not in ("current", "prediction"):
            raise ValueError(f"output must be 'current' or 'prediction', got {self.output!r}")

    def _component(self) -> Component:
        return cpx_linearized(_plant_vector_field, self.h, self.model.m, keep=self.keep, output=self.output,
                              from_truth=self.from_truth, svd=self.svd, expm_squarings=self.expm_squarings)

    def init(self, key, x0):
        return self._component().init(self, key, x0)

    def step(self, state, y, u_prev, key, k):
        state, out = self._component().step(self, state, (y, u_prev), key, k)
        return state, out, state.xc
