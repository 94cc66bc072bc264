"""Maximum marginal likelihood for linear-Gaussian state-space models, over many sequences at once.

``build(theta) -> LGSSMModel`` maps the parameters being fitted (noise scale factors, a plant's damping, whole
covariance matrices) to the model; ``fit_marginal_likelihood`` maximises

    sum_i log p(y^(i)_0..T-1 | theta)        (the Kalman filter's prediction-error decomposition, vmapped over i)

with an optax optimiser (Adam after gradient clipping by default, or ``optax.lbfgs()``) in the unconstrained
coordinates u of ``spec`` (``Log()`` for scale factors, ``SPDFactor()`` for covariances, ``Bounded`` ...). The
loss L(u) handed to the optimiser is the negative log-likelihood per sequence and time step, so one learning
rate and one tolerance suit any batch size and length.

Stopping rule. The fit stops at the first iterate with ||grad L(u)||_2 <= ``tol`` (status ``"converged"``), after
``max_iter`` updates (``"max_iterations"``), or at a loss or gradient that is not finite (``"not_finite"``).
The returned theta is the converged iterate, or else the best (lowest-loss) one seen. An optimiser that keeps
the value and gradient in its state (``optax.lbfgs``: its line search evaluates them at the accepted point) has
them reused (``optax.value_and_grad_from_state``) and receives ``value``, ``grad`` and ``value_fn`` in its
update; Adam ignores them.

Missing data (``mask`` (B, T) or (B, T, p), ``nan_missing``) and feedthrough (``LGSSMModel.D``) are those of
``jaxdip.estimators.recorded``; the model's matrices may be stacks over time with its natural indexing
(``jaxdip.estimators.kf``).

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
import numpy as np

from jaxdip.engine import checks
from jaxdip.progress import Progress
from jaxdip.tune.transforms import unconstrained_spec, to_constrained, to_unconstrained
from jaxdip.tune.tuner import default_optimizer


from jaxdip._public import public_dir

__all__ = ["LGSSMModel", "STATUSES", "LikelihoodFit", "total_log_likelihood", "fit_marginal_likelihood"]
__dir__ = public_dir(globals())


class LGSSMModel(NamedTuple):
    """x_0 ~ N(m0, P0), x_{k+1} = Phi x_k + W u_k + w, y_k = C x_k + D u_k + v (see
    ``jaxdip.estimators.recorded``); R a scalar, a diagonal or a full matrix."""

    Phi: Any
    C: Any
    Q: Any
    R: Any
    m0: Any
    P0: Any
    W: Any = None
    D: Any = None


STATUSES = ("converged", "max_iterations", "not_finite")


class LikelihoodFit(NamedTuple):
    theta: Any  # the converged iterate, or the best one seen (module doc)
    log_likelihood: jax.Array  # total over all sequences at theta
    stderr: Any  # standard errors of theta (curvature + delta method), same structure as theta
    cov_u: jax.Array  # inverse observed information in the flattened unconstrained coordinates
    grad_norm: jax.Array  # norm of the gradient of the total log-likelihood in u at theta
    status: str  # one of STATUSES
    iterations: int  # optimiser updates applied
    loss_history: np.ndarray  # L(u) at every iterate evaluated (per sequence and time step)
    grad_norm_history: np.ndarray  # ||grad L(u)|| there


def total_log_likelihood(model: LGSSMModel, ys, us=None, mask=None, nan_missing: bool = False) -> jax.Array:
    """sum_i log p(y^(i)) for ``ys`` (B, T, p) (and ``us`` (B, T, m), ``mask`` (B, T) or (B, T, p)), vmapped over
    the sequences."""
    kf = KalmanFilter(model.Phi, model.W, model.C, model.Q, model.R, model.P0, model.m0)
    needs_u = model.W is not None or model.D is not None

    def one(y, u, m):
        return log_likelihood(kf, y, u if needs_u else None, mask=m, nan_missing=nan_missing, D=model.D)

    B = ys.shape[0]
    us = jnp.zeros((B, ys.shape[1], 1), ys.dtype) if us is None else us
    if mask is None:
        return jnp.sum(jax.vmap(lambda y, u: one(y, u, None))(ys, us))
    return jnp.sum(jax.vmap(one)(ys, us, jnp.asarray(mask)))


def fit_marginal_likelihood(build: Callable[[Any], LGSSMModel], theta0, ys, us=None, *, mask=None,
                            nan_missing: bool = False, spec=None, optimizer=None, lr: float = 0.05,
                            clip: Optional[float] = 1.0, tol: float = 1e-6, max_iter: int = 1000,
                            progress: bool = False) -> LikelihoodFit:
    """Maximise the marginal likelihood of ``ys`` (B, T, p) over theta (starting at ``theta0``) until
    ||grad L(u)|| <= ``tol`` or ``max_iter`` updates (module doc). ``optimizer``: an optax transformation
    (default: ``clip_by_global_norm(clip)`` then ``adam(lr)``); ``optax.lbfgs()`` works as it is."""
    import optax

    ys = jnp.asarray(ys, dtype=jnp.result_type(float))
    if ys.ndim != 3:
        raise checks.ArgumentError(f"ys must be (B, T, p) (a batch of sequences), got shape {checks.fmt_shape(ys.shape)}")
    checks.check_int("fit_marginal_likelihood", "max_iter", max_iter, 1)
    checks.check_positive("fit_marginal_likelihood", "tol", tol)
    us = None if us is None else jnp.asarray(us, dtype=ys.dtype)
    spec = unconstrained_spec(theta0) if spec is None else spec
    scale = 1.0 / (ys.shape[0] * ys.shape[1])

    def neg_ll(theta):
        return -total_log_likelihood(build(theta), ys, us, mask, nan_missing)

    def loss(u):
        return scale * neg_ll(to_constrained(spec, u))

    opt = optax.with_extra_args_support(optimizer or default_optimizer(lr, clip))
    u = to_unconstrained(spec, theta0)
    state = opt.init(u)
    reuse = optax.tree.get(state, "value") is not None
    value_and_grad = optax.value_and_grad_from_state(loss) if reuse else jax.value_and_grad(loss)

    @jax.jit
    def step(u, state):
        v, g = value_and_grad(u, state=state) if reuse else value_and_grad(u)
        upd, state = opt.update(g, state, u, value=v, grad=g, value_fn=loss)
        return optax.apply_updates(u, upd), state, v, optax.tree.norm(g)

    losses, gnorms = [], []
    best_u, best_loss, status = u, np.inf, "max_iterations"
    bar = Progress(max_iter, "likelihood", enabled=progress)
    for _ in range(max_iter + 1):
        u_next, state_next, v, gn = step(u, state)
        v, gn = float(v), float(gn)
        losses.append(v)
        gnorms.append(gn)
        if not (np.isfinite(v) and np.isfinite(gn)):
            status = "not_finite"
            break
        if v < best_loss:
            best_u, best_loss = u, v
        if gn <= tol:
            best_u, status = u, "converged"
            break
        if len(losses) > max_iter:
            break  # the last evaluation only checks the final iterate
        u, state = u_next, state_next
        bar.update(1)
    bar.close()
    iterations = len(losses) - 1
    theta = to_constrained(spec, best_u)
    u_flat, unravel = ravel_pytree(best_u)

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
    return LikelihoodFit(theta, -nll, unravel_theta(jnp.sqrt(var_theta)), cov_u, jnp.linalg.norm(g), status,
                         iterations, np.asarray(losses), np.asarray(gnorms))
