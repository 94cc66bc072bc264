"""Maximum marginal likelihood for linear-Gaussian state-space models, over many sequences at once.

``build(theta) -> LGSSMModel`` maps the parameters being fitted (noise scale factors, a plant's damping, whole
covariance matrices) to the model; ``fit_marginal_likelihood`` maximises

    sum_i log p(y^(i)_0..T-1 | theta)        (the Kalman filter's prediction-error decomposition, vmapped over i)

with ``jaxdip.tune.tune`` (optax, Adam by default) in the unconstrained coordinates of ``spec`` (``Log()`` for
scale factors, ``SPDFactor()`` for covariances, ``Bounded`` ...). The loss handed to the optimiser is the
negative log-likelihood per sequence and time step, so one learning rate suits any batch size and length.

Statistical error. At the maximum the observed information is the Hessian H of the total negative
log-likelihood in u (central differences of the exact gradient); its inverse is the asymptotic covariance of u,
and the delta method through the transform gives the standard errors of theta (``LikelihoodFit.stderr``). They
are what "recovered within the statistical error" is measured against.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from jaxdip.estimators.kf import KalmanFilter
from jaxdip.estimators.recorded import log_likelihood
from jaxdip.tune.transforms import unconstrained_spec, to_constrained, to_unconstrained
from jaxdip.tune.tuner import TuneResult, tune


from jaxdip._public import public_dir

__all__ = ["LGSSMModel", "LikelihoodFit", "total_log_likelihood", "fit_marginal_likelihood"]
__dir__ = public_dir(globals())


class LGSSMModel(NamedTuple):
    """x_0 ~ N(m0, P0), x_{k+1} = Phi x_k + W u_k + w, y_k = C x_k + v (see ``jaxdip.estimators.recorded``)."""

    Phi: Any
    C: Any
    Q: Any
    R: Any
    m0: Any
    P0: Any
    W: Any = None


class LikelihoodFit(NamedTuple):
    theta: Any  # maximiser (the best iterate of the optimiser)
    log_likelihood: jax.Array  # total over all sequences at theta
    stderr: Any  # standard errors of theta (curvature + delta method), same structure as theta
    cov_u: jax.Array  # inverse observed information in the flattened unconstrained coordinates
    grad_norm: jax.Array  # norm of the gradient of the total log-likelihood in u at theta
    run: TuneResult  # the optimiser's history


def total_log_likelihood(model: LGSSMModel, ys, us=None) -> jax.Array:
    """sum_i log p(y^(i)) for ``ys`` (B, T, p) (and ``us`` (B, T, m)), vmapped over the sequences."""

    def one(y, u):
        kf = KalmanFilter(model.Phi, model.W, model.C, model.Q, model.R, model.P0, model.m0)
        return log_likelihood(kf, y, None if model.W is None else u)

    if us is None:
        return jnp.sum(jax.vmap(lambda y: one(y, None))(ys))
    return jnp.sum(jax.vmap(one)(ys, us))


def fit_marginal_likelihood(build: Callable[[Any], LGSSMModel], theta0, ys, us=None, *, spec=None,
                            steps: int = 300, lr: float = 0.05, optimizer=None, clip: Optional[float] = 1.0,
                            progress: bool = False) -> LikelihoodFit:
    """Maximise the marginal likelihood of ``ys`` (B, T, p) over theta (starting at ``theta0``)."""
    ys = jnp.asarray(ys, dtype=jnp.result_type(float))
    us = None if us is None else jnp.asarray(us, dtype=ys.dtype)
    spec = unconstrained_spec(theta0) if spec is None else spec
    scale = 1.0 / (ys.shape[0] * ys.shape[1])

    def neg_ll(theta):
        return -total_log_likelihood(build(theta), ys, us)

    run = tune(lambda theta, key: scale * neg_ll(theta), theta0, jax.random.PRNGKey(0), steps=steps, lr=lr,
               spec=spec, optimizer=optimizer, clip=clip, progress=progress, desc="likelihood")
    theta = run.theta
    u_flat, unravel = ravel_pytree(to_unconstrained(spec, theta))

    def nll_u(v):
        return neg_ll(to_constrained(spec, unravel(v)))

    # Hessian by central differences of the exact (forward-mode) gradient: accurate to ~1e-8 relative, and a
    # nested autodiff Hessian through the scan costs several times the compile time for no useful digit
    vg = jax.jit(lambda v: (nll_u(v), jax.jacfwd(nll_u)(v)))
    nll, g = vg(u_flat)
    eps = 1e-4
    n = u_flat.shape[0]
    cols = [(vg(u_flat + eps * e)[1] - vg(u_flat - eps * e)[1]) / (2 * eps) for e in jnp.eye(n, dtype=u_flat.dtype)]
    H = jnp.stack(cols, axis=1)
    cov_u = jnp.linalg.inv(0.5 * (H + H.T))
    J = jax.jacfwd(lambda v: ravel_pytree(to_constrained(spec, unravel(v)))[0])(u_flat)
    var_theta = jnp.diag(J @ cov_u @ J.T)
    _, unravel_theta = ravel_pytree(theta)
    return LikelihoodFit(theta, -nll, unravel_theta(jnp.sqrt(var_theta)), cov_u, jnp.linalg.norm(g), run)
