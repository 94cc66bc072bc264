"""The roles of a closed loop as ``equinox.Module``s: plant, sensor, estimator, controller, actuator.

A component *is* its hyperparameters: numbers are array fields (traced, differentiable, vmappable, changed with
``eqx.tree_at``), structure is ``eqx.field(static=True)`` (dimensions, variants, flags). One protocol per role,
each an ``init``/``step`` pair over an explicit state pytree; ``step`` returns ``(state, output, aux)``, where
``aux`` is anything the component wants a caller to be able to record (a covariance, adapted weights, a bias
estimate) or ``None``:

    Sensor      init(key, x0) -> s     step(s, x, key, k)            -> (s, y, aux)
    Estimator   init(key, x0) -> s     step(s, y, u_prev, key, k)    -> (s, xhat, aux)
    Controller  init(key, x0) -> s     step(s, xhat, key, k)         -> (s, u, aux)
    Actuator    init(key, x0) -> s     step(s, u, key, k)            -> (s, u_applied, aux)

``x0`` is the true initial plant state (an estimator may start from it or ignore it); ``k`` is the period
index. A plant is continuous (``vector_field(x, u)``, integrated by RK4 sub-steps under a zero-order hold) or
discrete (``step(x, u)``); it names its states and inputs (``state_names``, ``input_names``) and may override
``equilibrium()``, the point the loop's state bound is measured from.

This module imports only the engine's own modules (RK4), so plants and sensors can subclass
these roles without import cycles.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from jaxdip.engine import checks
from jaxdip.engine.integrate import rk4_zoh


from jaxdip._public import public_dir

__all__ = ["param", "dtype_of", "Plant", "DiscretePlant", "rhs", "linearize", "Sensor", "Estimator", "Controller", "Actuator", "Identity",
           "Passthrough", "FanOutAux", "FanOut"]
__dir__ = public_dir(globals())


def dtype_of(x) -> jnp.dtype:
    """The floating dtype a component's state and draws follow: that of ``x`` (a loop's state, float32 in a
    float32 loop), or the default float (float64 under jaxdip) for anything not floating (or None)."""
    if x is None:
        return jnp.result_type(float)
    dt = jnp.result_type(x)
    return dt if jnp.issubdtype(dt, jnp.floating) else jnp.result_type(float)


def _as_float_array(v):
    return jnp.asarray(v, dtype=jnp.result_type(float))


class _ToFloatArray:
    """``param``'s converter, told its field's name and class by ``_ParamField.__set_name__``: a string, an
    object or a complex number is refused with an ``ArgumentTypeError`` naming both, not deep in JAX's converter
    (the class is the one that declares the field, e.g. ``TWIP`` for ``TWIPUnmodeled``'s inherited constants)."""

    def __init__(self):
        self.owner, self.name = "param", "value"

    def __call__(self, v):
        checks.check_real(self.owner, self.name, v)
        try:
            return _as_float_array(v)
        except (TypeError, ValueError) as e:  # a ragged list, an object with a dtype JAX cannot take
            raise checks.ArgumentTypeError(f"{self.owner}: {self.name} must be real numbers, got "
                                           f"{type(v).__name__} ({e})") from None


class _ParamField(dataclasses.Field):
    # Python calls __set_name__ on every attribute of a class body as the class is made: the only moment a
    # field learns its own name and class, which a converter (called with the value alone) otherwise never knows
    __slots__ = ()

    def __set_name__(self, owner, name):
        conv = self.metadata.get("converter")
        if isinstance(conv, _ToFloatArray):
            conv.owner, conv.name = owner.__name__, name
        super().__set_name__(owner, name)


def param(default: Any = dataclasses.MISSING, **kw):
    """A hyperparameter field: stored as a float array (float64 under jaxdip), so it is traced, not static.

    ``eqx.field(converter=...)`` runs on construction only; ``eqx.tree_at`` and ``vmap`` may put tracers or
    batched arrays in the field unchanged. A value that is not real numbers (a string, a complex number) raises
    ``ArgumentTypeError`` naming the class and the field.
    """
    f = eqx.field(default=default, converter=_ToFloatArray(), **kw)
    f.__class__ = _ParamField  # same slots, one more method: dataclasses still sees a Field
    return f


# ---- plants -------------------------------------------------------------------------------------------------


def _call_vector_field(plant, x, u):
    return plant.vector_field(x, u)


_rhs_program = eqx.filter_jit(_call_vector_field)


def rhs(plant: "Plant", x, u) -> jax.Array:
    """``plant.vector_field(x, u)`` as a program of its own, traced once per plant structure and argument shapes.

    A loop calls its plant's right-hand side four times per RK4 step, and again in every linearisation,
    derivative and gradient taken through it; called directly, each of those calls traces the plant's Python
    anew (20 ms for the printed DIP's equations). Through ``rhs`` an enclosing trace takes the jaxpr traced the
    first time (``vmap`` and autodiff transform it whole), and XLA inlines the call, so the compiled code and its
    results are the same. Integrators, linearisations and the controllers and estimators that differentiate a
    plant model call it. Module-level: one function object for every plant instance.
    """
    return _rhs_program(plant, x, u)


class Plant(eqx.Module):
    """A continuous plant: subclasses define ``vector_field(x, u) -> xdot`` and the class attributes
    ``state_names`` and ``input_names``."""

    state_names = ()
    input_names = ("u",)
    continuous = True

    @property
    def n(self) -> int:
        return len(self.state_names)

    @property
    def m(self) -> int:
        return len(self.input_names)

    def index(self, name: str) -> int:
        """Position of a state by name: weights and noise levels are mapped by name, never by position."""
        try:
            return tuple(self.state_names).index(name)
        except ValueError:
            raise KeyError(f"{type(self).__name__} has no state {name!r}; states are {self.state_names}") from None

    def equilibrium(self) -> jax.Array:
        """The operating point the loop's state bound is measured from (the origin unless overridden)."""
        return jnp.zeros(self.n)

    @abc.abstractmethod
    def vector_field(self, x, u) -> jax.Array:
        ...

    def period(self, x, u, dt: float, substeps: int) -> jax.Array:
        """x after one sample period ``dt`` with ``u`` held: ``substeps`` RK4 steps."""
        return rk4_zoh(rhs, self, x, u, dt, substeps)


class DiscretePlant(Plant):
    """A discrete-time plant: subclasses define ``step(x, u) -> x_next`` (one sample period)."""

    continuous = False

    def vector_field(self, x, u):
        raise TypeError(f"{type(self).__name__} is a discrete plant: it has step(x, u), not a vector field")

    @abc.abstractmethod
    def step(self, x, u) -> jax.Array:
        ...

    def period(self, x, u, dt: float, substeps: int) -> jax.Array:
        return self.step(x, jnp.asarray(u))


def linearize(plant: Plant, x=None, u=None) -> tuple[jax.Array, jax.Array]:
    """(A, B): Jacobians of the vector field (or of the discrete map) at (x, u) by forward-mode autodiff.

    Defaults: the plant's equilibrium and a zero input. Compiled per plant structure, so repeated calls (a
    sweep over plant parameters) reuse one program.
    """
    if not isinstance(plant, Plant):
        raise checks.ArgumentTypeError(f"linearize: plant must be a jaxdip Plant, got {type(plant).__name__}")
    for name, v, size, what in (("x", x, plant.n, "states"), ("u", u, plant.m, "inputs")):
        if v is not None:
            checks.check_real("linearize", name, v)
            if name == "u" and checks.shape_of(v) == () and size == 1:
                continue
            checks.check_shape("linearize", name, v, (size,), f"for {type(plant).__name__} ({size} {what})")
    x = plant.equilibrium() if x is None else jnp.asarray(x, dtype=jnp.result_type(float))
    u = jnp.zeros(plant.m) if u is None else jnp.atleast_1d(jnp.asarray(u, dtype=jnp.result_type(float)))
    return _jacobians(plant, x, u)


def _discrete_map(plant, x, u):
    return plant.step(x, u)


@eqx.filter_jit
def _jacobians(plant, x, u):
    # x and u are arguments, not constants made inside: XLA would fold them and round differently
    f = rhs if plant.continuous else _discrete_map
    A = jax.jacfwd(f, argnums=1)(plant, x, u)
    B = jax.jacfwd(f, argnums=2)(plant, x, u)
    return A, B.reshape(x.shape[0], u.shape[0])


# ---- sensors, estimators, controllers, actuators ------------------------------------------------------------

# ``io_sizes()`` is what ``Loop`` checks its parts against each other with when it is built: a dict of the
# sizes a component knows from its own fields, each as ``(size, why)`` ("C is (4, 6)"), under the keys
#   "in"   the size of what it reads (a sensor: the plant state; an estimator: y; a controller: xhat;
#          an actuator: u),
#   "out"  the size of what it hands on (or ``SAME``: as large as what it reads),
#   "u"    an estimator's input size u_{k-1}.
# A size a component does not know is left out; the default knows none, so a user's component is never
# rejected for not declaring them.
SAME = "same"


def _io_default(self) -> dict:
    return {}



class Sensor(eqx.Module):
    def init(self, key, x0):
        return ()

    io_sizes = _io_default

    @abc.abstractmethod
    def step(self, state, x, key, k):
        """-> (state, y, aux)"""


def _structural_hash(self) -> int:
    # equinox hashes a module by its fields, and arrays are unhashable, so ``jax.jit(est.step)`` (which hashes
    # the bound method, a module holding ``est``) failed. This hash keeps the contract with equinox's ``__eq__``
    # (``tree_equal``): equal modules have equal structure, static fields and leaf shapes/dtypes, so equal
    # hashes; modules that differ only in array values collide and ``__eq__`` tells them apart.
    leaves, treedef = jax.tree_util.tree_flatten(self)

    def key(leaf):
        if hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
            return ("array", tuple(leaf.shape), str(leaf.dtype))
        try:
            return hash(leaf)
        except TypeError:
            return type(leaf).__name__

    return hash((treedef, tuple(key(leaf) for leaf in leaves)))


class Estimator(eqx.Module):
    """Estimator role. ``jax.jit(est.step)`` works: the hash is structural (``_structural_hash``), so the bound
    method is hashable and its array fields become constants of the compiled step; to trace the fields instead
    (no recompile when a value changes) use ``eqx.filter_jit(type(est).step)(est, ...)``."""

    __hash__ = _structural_hash

    def init(self, key, x0):
        return ()

    io_sizes = _io_default

    @abc.abstractmethod
    def step(self, state, y, u_prev, key, k):
        """-> (state, xhat, aux)"""


class Controller(eqx.Module):
    def init(self, key, x0):
        return ()

    io_sizes = _io_default

    @abc.abstractmethod
    def step(self, state, xhat, key, k):
        """-> (state, u, aux)"""


class Actuator(eqx.Module):
    def init(self, key, x0):
        return ()

    io_sizes = _io_default

    @abc.abstractmethod
    def step(self, state, u, key, k):
        """-> (state, u_applied, aux)"""


class Identity(Actuator):
    """The ideal actuator (and a do-nothing stage of any role with one input): output = input."""

    def step(self, state, u, key, k):
        return state, u, None

    def io_sizes(self) -> dict:
        return {"out": (SAME, "the identity")}


class Passthrough(Estimator):
    """The measurement is the estimate (full-state measurement)."""

    def step(self, state, y, u_prev, key, k):
        return state, y, None

    def io_sizes(self) -> dict:
        return {"out": (SAME, "the measurement is the estimate")}


class FanOutAux(NamedTuple):
    xhat: dict  # name -> that estimator's output
    aux: dict  # name -> that estimator's aux


class FanOut(Estimator):
    """Several estimators fed the same measurements and inputs; the controller gets ``estimators[drive]``.

    Every estimator receives the same keys (at init and at every step) as a single estimator in this place
    would, so the driving estimator's trajectory is exactly the one of a loop without the others, and the
    others are compared on identical noise. ``aux`` is a ``FanOutAux`` with every estimator's output and aux.
    """

    estimators: dict
    drive: str = eqx.field(static=True)

    def __check_init__(self):
        if self.drive not in self.estimators:
            checks.fail(self, f"drive must be one of the estimators {sorted(self.estimators)}, got {self.drive!r}")

    def io_sizes(self) -> dict:
        # the controller sees the driving estimator's output; every estimator reads the same y and u
        def of(e):
            return e.io_sizes() if callable(getattr(e, "io_sizes", None)) else {}

        sizes = dict(of(self.estimators[self.drive]))
        for name, e in self.estimators.items():
            for key, (size, why) in of(e).items():
                if key == "out" or size == SAME:
                    continue
                if key in sizes and sizes[key][0] != size:
                    checks.fail(self, f"estimators[{name!r}] reads {size} {'inputs' if key == 'u' else 'values'} "
                                f"({why}) but estimators[{self.drive!r}] reads {sizes[key][0]} ({sizes[key][1]})")
                sizes.setdefault(key, (size, f"estimators[{name!r}]: {why}"))
        return sizes

    def init(self, key, x0):
        return {name: e.init(key, x0) for name, e in self.estimators.items()}

    def step(self, state, y, u_prev, key, k):
        new, outs, auxes = {}, {}, {}
        for name, e in self.estimators.items():
            new[name], outs[name], auxes[name] = e.step(state[name], y, u_prev, key, k)
        return new, outs[self.drive], FanOutAux(outs, auxes)
