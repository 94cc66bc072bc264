"""Engine estimators used outside the engine: ``jax.jit(est.step)`` (a bound method of an equinox module) and
``eqx.filter_jit`` of the unbound step equal the eager step, for every estimator class in jaxdip.estimators."""

import inspect

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip import estimators as E
from jaxdip.estimators import bias_observers as bo
from jaxdip.estimators import complementary, homd, luenberger
from jaxdip.estimators.dmso import DMSO, selection_matrix
from jaxdip.plants import lorenz, rwp
from jaxdip.sim.discretize import Discrete

DT = 0.01
PHI = np.array([[1.0, 0.1, 0.0], [0.0, 1.0, 0.1], [0.0, -0.2, 0.95]])
W = np.array([[0.0], [0.0], [0.1]])
C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
Q, R, P0 = 0.01 * np.eye(3), 0.1 * np.eye(2), np.eye(3)
X0 = np.array([0.3, -0.2, 0.1])


def _kf():
    return E.KalmanFilter(PHI, W, C, Q, R, P0, X0)


def _ekf():
    return E.ExtendedKalmanFilter(Q, R, P0, X0, f=lambda x, u: PHI @ x + W @ u + 0.01 * jnp.sin(x), C=C)


def _ukf():
    return E.UnscentedKalmanFilter(lambda x, u: PHI @ x + W @ u + 0.01 * jnp.sin(x), lambda x: C @ x, Q, R, P0, X0)


def _rwp_homd():
    return homd.HOMDObserver.build(DT, substeps=2)


# class -> (estimator, y size, u size, x0 size); one entry per concrete estimator class (checked below)
FACTORIES = {
    E.KalmanFilter: lambda: (_kf(), 2, 1, 3),
    E.ExtendedKalmanFilter: lambda: (_ekf(), 2, 1, 3),
    E.UnscentedKalmanFilter: lambda: (_ukf(), 2, 1, 3),
    E.CPX: lambda: (E.CPX(0.5, Discrete(PHI, np.linalg.inv(PHI), W), C, X0), 2, 1, 3),
    E.LinearizedCPX: lambda: (E.LinearizedCPX(0.5, lorenz.Lorenz(), lorenz.output_matrix(), X0, h=0.001), 2, 1, 3),
    E.LeastSquaresMHE: lambda: (E.LeastSquaresMHE(1.0, PHI, W, C, X0, N=3), 2, 1, 3),
    E.WeightedMHE: lambda: (E.WeightedMHE.from_noise(Discrete(PHI, np.linalg.inv(PHI), W), C, Q, R, N=3), 2, 1, 3),
    E.TimeVaryingMHE: lambda: (E.TimeVaryingMHE(np.linalg.inv(R), np.linalg.inv(Q), np.eye(3), f=lambda x, u: PHI @ x
                                                + W @ u + 0.01 * jnp.sin(x), C=C, N=1, xhat0=X0), 2, 1, 3),
    E.LDF: lambda: (E.LDF(np.array([30.0, 20.0]), 0.9, n_pos=2, dt=DT), 2, 1, 4),
    E.DMSO: lambda: (DMSO.thesis(np.eye(4) + 0.01 * np.eye(4, k=1), 0.01 * np.ones((4, 1)),
                                 np.asarray(selection_matrix(4, (1, 3))), K=0.5 * np.eye(4), Gamma=0.1), 4, 1, 4),
    complementary.ComplementaryFilter: lambda: (complementary.ComplementaryFilter(0.98, DT, 0, 1), 2, 1, 2),
    homd.HOMDObserver: lambda: (_rwp_homd(), 2, 1, 4),
    luenberger.LuenbergerObserver: lambda: (
        luenberger.LuenbergerObserver.build(DT, np.ones((4, 2)) * 0.1, substeps=2), 2, 1, 4),
    bo.LowpassHOMD: lambda: (bo.LowpassHOMD.build(_rwp_homd(), 0.05), 2, 1, 4),
    bo.LowpassMeasured: lambda: (bo.LowpassMeasured.build(DT, 0.5), 4, 1, 4),
    bo.ReducedOrderMeasured: lambda: (bo.ReducedOrderMeasured.build(DT, rwp.RWP(), 0.05), 4, 1, 4),
    bo.JointObserver: lambda: (bo.JointObserver.build(_rwp_homd(), 0.01), 2, 1, 4),
    E.Prior: lambda: (E.Prior(_kf()), 2, 1, 3),
    E.Ahead: lambda: (E.Ahead(E.CPX(0.5, Discrete(PHI, np.linalg.inv(PHI), W), C, X0)), 2, 1, 3),
    E.Delayed: lambda: (E.Delayed(_kf()), 2, 1, 3),
    E.DelayedMeasurement: lambda: (E.DelayedMeasurement(_kf(), np.zeros(2)), 2, 1, 3),
    E.FromTruth: lambda: (E.FromTruth(_ukf()), 2, 1, 3),
    E.InitialError: lambda: (E.InitialError(_ekf(), 0.5), 2, 1, 3),
    jd.Passthrough: lambda: (jd.Passthrough(), 3, 1, 3),
    jd.FanOut: lambda: (jd.FanOut({"kf": _kf(), "ukf": _ukf()}, drive="kf"), 2, 1, 3),
}


def _concrete_estimator_classes():
    import jaxdip.estimators as pkg
    import pkgutil

    found = {jd.Passthrough, jd.FanOut}
    for info in pkgutil.iter_modules(pkg.__path__):
        mod = __import__(f"jaxdip.estimators.{info.name}", fromlist=["_"])
        for _, cls in inspect.getmembers(mod, inspect.isclass):
            if (issubclass(cls, jd.Estimator) and cls.__module__.startswith("jaxdip.estimators")
                    and not cls.__name__.startswith("_") and not inspect.isabstract(cls)
                    and cls.__name__ != "SampledObserver"):
                found.add(cls)
    return found


def test_every_estimator_class_is_covered():
    missing = _concrete_estimator_classes() - set(FACTORIES)
    assert not missing, f"add a factory for {sorted(c.__name__ for c in missing)}"


def _close(a, b):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-12, atol=1e-12)


# compiling (and running op by op) an RK4-substepped observer or a relinearising CPX takes seconds: slow suite
SLOW = {E.LinearizedCPX, homd.HOMDObserver, luenberger.LuenbergerObserver, bo.LowpassHOMD, bo.JointObserver,
        bo.ReducedOrderMeasured}
CLASSES = [pytest.param(c, marks=pytest.mark.slow) if c in SLOW else c for c in FACTORIES]


def _steps(est, p, m, n, step, *lead):
    rng = np.random.default_rng(0)
    key = jax.random.PRNGKey(1)
    s = est.init(key, jnp.asarray(rng.normal(size=n) * 0.1))
    out = []
    for k in range(2):  # k = 0 is a special case in most estimators
        y, u = jnp.asarray(0.1 * rng.normal(size=p)), jnp.asarray(0.1 * rng.normal(size=m))
        s, xhat, aux = step(*lead, s, y, u, jax.random.fold_in(key, k), k)
        out.append((s, xhat, aux))
    return out


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_jit_of_step_equals_the_eager_step(cls):
    est, p, m, n = FACTORIES[cls]()
    # a bound method: hashable since the estimator's hash is structural; its fields are compiled in as constants
    _close(_steps(est, p, m, n, jax.jit(est.step)), _steps(est, p, m, n, est.step))


@pytest.mark.parametrize("cls", [E.KalmanFilter, E.UnscentedKalmanFilter, E.WeightedMHE, jd.FanOut],
                         ids=lambda c: c.__name__)
def test_filter_jit_of_the_unbound_step_equals_the_eager_step(cls):
    est, p, m, n = FACTORIES[cls]()
    # the estimator as an argument: its array fields are traced (no recompile when a value changes)
    _close(_steps(est, p, m, n, eqx.filter_jit(type(est).step), est), _steps(est, p, m, n, est.step))


def test_jit_keeps_estimators_that_differ_in_values_apart():
    """Two filters of one structure hash alike; equality (equinox's tree_equal) keeps their compiled steps
    apart, so each jitted step gives its own filter's numbers."""
    a, b = _kf(), eqx.tree_at(lambda e: e.R, _kf(), 5.0 * np.asarray(R))
    assert hash(a) == hash(b) and not (a == b)
    s = a.init(None, X0)
    y, u = jnp.array([1.0, -1.0]), jnp.zeros(1)
    for e in (a, b, a):
        _close(jax.jit(e.step)(s, y, u, None, 1), e.step(s, y, u, None, 1))
    assert not np.allclose(jax.jit(a.step)(s, y, u, None, 1)[1], jax.jit(b.step)(s, y, u, None, 1)[1])
