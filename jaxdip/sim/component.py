"""The component interface every sensor, estimator, controller and actuator follows.

Like an optax transformation, a component is a pair of pure functions over an explicit state pytree, and its
hyperparameters are a pytree *argument* (never closed-over Python floats), so ``jax.grad`` and ``vmap`` reach
them:

    state = init(params, key, x0)
    state, out = step(params, state, inp, key, k)

``x0`` is the true initial plant state (an estimator may start from it, from an offset of it, or ignore it);
``k`` is the sample index, for time-varying laws. Inputs per role: a sensor gets the true state ``x``; an
estimator gets ``(y, u_prev)``; a controller gets the estimate ``xhat``; an actuator gets the commanded ``u``.
"""

from __future__ import annotations

from typing import Callable, NamedTuple


class Component(NamedTuple):
    init: Callable
    step: Callable


def stateless(fn: Callable) -> Component:
    """A component with no state: ``out = fn(params, inp, key, k)``."""

    def init(params, key, x0):
        return ()

    def step(params, state, inp, key, k):
        return state, fn(params, inp, key, k)

    return Component(init, step)


identity = stateless(lambda params, inp, key, k: inp)


def chain(*components: Component) -> Component:
    """Apply components in order; params and state are tuples with one entry per component."""
    import jax

    def init(params, key, x0):
        keys = jax.random.split(key, len(components))
        return tuple(c.init(p, kk, x0) for c, p, kk in zip(components, params, keys))

    def step(params, state, inp, key, k):
        keys = jax.random.split(key, len(components))
        new_state = []
        out = inp
        for c, p, s, kk in zip(components, params, state, keys):
            s, out = c.step(p, s, out, kk, k)
            new_state.append(s)
        return tuple(new_state), out

    return Component(init, step)
