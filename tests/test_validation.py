"""Wrong shapes, dtypes and values of the public constructors and functions: one ``ArgumentError`` (a
``ValueError``; ``ArgumentTypeError``, also a ``TypeError``, for dtypes) whose message names the class or function
and the argument, raised before anything is traced.

"Before anything is traced" is enforced, not assumed: every case runs with JAX's tracing entry points (``jit``'s
inner loops ``lax.scan``/``fori_loop``/``while_loop``, ``vmap``, ``jacfwd``, ``eval_shape``, ``make_jaxpr``)
replaced by functions that fail the test, so a check that only fires inside a trace would fail here. The valid
pieces (a linearised, discretised DIP) are built once, outside that guard.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.control.riccati import RiccatiError
from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.estimators import CPX, LDF, ExtendedKalmanFilter, InitialError, KalmanFilter, LeastSquaresMHE, WeightedMHE
from jaxdip.estimators import FromTruth, UnscentedKalmanFilter
from jaxdip.sim.actuators import Deadzone, Saturation
from jaxdip.sim.disturbance import InputDisturbance
from jaxdip.sim.dip_sensors import output_matrix
from jaxdip.sim.sensors import LinearSensor, WhiteNoise

DT = 0.01
TRACERS = [(jax.lax, "scan"), (jax.lax, "fori_loop"), (jax.lax, "while_loop"), (jax, "vmap"), (jax, "jacfwd"),
           (jax, "eval_shape"), (jax, "make_jaxpr")]


@pytest.fixture(scope="module")
def dip():
    plant = jd.plants.DIP()
    A, B = jd.linearize(plant)
    model = jd.zoh(A, B, DT)
    K = jd.control.lqr(A, B, np.eye(6), np.eye(1))[0]
    return dict(plant=plant, A=np.asarray(A), B=np.asarray(B), model=model, K=np.asarray(K),
                C3=np.asarray(output_matrix(plant.state_names)))


@pytest.fixture
def no_trace(monkeypatch):
    def forbid(name):
        def traced(*a, **k):
            raise AssertionError(f"{name} was called: the check did not run before tracing")
        return traced

    for mod, name in TRACERS:
        monkeypatch.setattr(mod, name, forbid(name))


def kf(d, **kw):
    m = d["model"]
    args = dict(Phi=m.Phi, W=m.W, C=d["C3"], Q=1e-6 * np.eye(6), R=1e-4 * np.eye(3), P0=1e-2 * np.eye(6))
    args.update(kw)
    return KalmanFilter(**args)


def loop(d, **kw):
    parts = dict(plant=d["plant"], sensor=WhiteNoise(1e-3), estimator=jd.Passthrough(),
                 controller=jd.control.StateFeedback(d["K"]), dt=DT)
    parts.update(kw)
    return jd.Loop(**parts)


NOT_PSD = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, -1.0])
ASYM = np.eye(6) + np.triu(np.ones((6, 6)), 1)

# (id, build(d), exception, match): ``match`` names the owner and the argument
CASES = [
    # Kalman filters
    ("kf-Q-shape", lambda d: kf(d, Q=np.eye(4)), ArgumentError,
     r"^KalmanFilter: Q must be \(6, 6\) for a 6-state model, got \(4, 4\)$"),
    ("kf-R-shape", lambda d: kf(d, R=np.eye(2)), ArgumentError, r"^KalmanFilter: R must be \(3, 3\) for 3 measurements"),
    ("kf-P0-psd", lambda d: kf(d, P0=NOT_PSD), ArgumentError,
     r"^KalmanFilter: P0 must be symmetric positive semidefinite, got smallest eigenvalue -1"),
    ("kf-Q-sym", lambda d: kf(d, Q=ASYM), ArgumentError, r"^KalmanFilter: Q must be symmetric"),
    ("kf-C-cols", lambda d: kf(d, C=np.eye(3, 4)), ArgumentError, r"^KalmanFilter: C must be \(\*, 6\)"),
    ("kf-xhat0", lambda d: kf(d, xhat0=np.zeros(4)), ArgumentError, r"^KalmanFilter: xhat0 must be \(6,\)"),
    ("kf-Phi-square", lambda d: kf(d, Phi=np.eye(6, 5)), ArgumentError, r"^KalmanFilter: Phi must be a square matrix"),
    ("kf-W-rows", lambda d: kf(d, W=np.zeros((4, 1))), ArgumentError, r"^KalmanFilter: W must be \(6, \*\)"),
    ("kf-Q-dtype", lambda d: kf(d, Q="eye"), ArgumentTypeError, r"^KalmanFilter: Q must be real numbers, got 'eye'"),
    ("kf-Q-complex", lambda d: kf(d, Q=1j * np.eye(6)), ArgumentTypeError, r"^KalmanFilter: Q must be real numbers"),
    ("kf-jitter", lambda d: kf(d, jitter=-1.0), ArgumentError, r"^KalmanFilter: jitter must be >= 0"),
    ("kf-Phi-nan", lambda d: kf(d, Phi=np.where(np.eye(6) > 0, np.nan, 0.0)), ArgumentError,
     r"^KalmanFilter: Phi must be finite, got nan at index \(0, 0\)"),
    ("ekf-Q-shape", lambda d: ExtendedKalmanFilter(np.eye(2), np.eye(2), np.eye(3), model=jd.plants.Lorenz(), dt=DT,
                                                   C=np.eye(2, 3)), ArgumentError,
     r"^ExtendedKalmanFilter: Q must be \(3, 3\) for a 3-state model"),
    ("ekf-f-and-model", lambda d: ExtendedKalmanFilter(np.eye(3), np.eye(2), np.eye(3), model=jd.plants.Lorenz(),
                                                       dt=DT, f=lambda x, u: x, C=np.eye(2, 3)), ArgumentError,
     r"^ExtendedKalmanFilter: give exactly one of f .* got both"),
    ("ekf-dt", lambda d: ExtendedKalmanFilter(np.eye(3), np.eye(2), np.eye(3), model=jd.plants.Lorenz(), dt=-0.1,
                                              C=np.eye(2, 3)), ArgumentError,
     r"^ExtendedKalmanFilter: dt must be positive"),
    ("ekf-model-size", lambda d: ExtendedKalmanFilter(np.eye(6), np.eye(2), np.eye(6), model=jd.plants.Lorenz(),
                                                      dt=DT, C=np.eye(2, 6)), ArgumentError,
     r"^ExtendedKalmanFilter: model must have 6 states like P0, got Lorenz with 3"),
    ("ukf-R-psd", lambda d: UnscentedKalmanFilter(lambda x, u: x, lambda x: x, np.eye(2), -np.eye(2), np.eye(2)),
     ArgumentError, r"^UnscentedKalmanFilter: R must be symmetric positive semidefinite"),
    ("ukf-alpha", lambda d: UnscentedKalmanFilter(lambda x, u: x, lambda x: x, np.eye(2), np.eye(2), np.eye(2),
                                                  alpha=0.0), ArgumentError, r"^UnscentedKalmanFilter: alpha must be positive"),
    # other estimators
    ("cpx-gamma", lambda d: CPX(-1.0, d["model"], d["C3"], np.zeros(6)), ArgumentError, r"^CPX: gamma must be positive"),
    ("cpx-C", lambda d: CPX(1.0, d["model"], np.eye(3, 5), np.zeros(6)), ArgumentError, r"^CPX: C must be \(\*, 6\)"),
    ("wmhe-meas-weight", lambda d: WeightedMHE(d["model"], d["C3"], np.eye(2), np.eye(6)), ArgumentError,
     r"^WeightedMHE: meas_weight must be \(3, 3\) for 3 measurements"),
    ("wmhe-anchor", lambda d: WeightedMHE(d["model"], d["C3"], np.eye(3), np.eye(6), N=2, anchor=2), ArgumentError,
     r"^WeightedMHE: anchor must satisfy 0 <= anchor < N = 2, got 2"),
    ("wmhe-box", lambda d: WeightedMHE(d["model"], d["C3"], np.eye(3), np.eye(6), lower=np.ones(6),
                                       upper=np.zeros(6)), ArgumentError, r"^WeightedMHE: lower must be <= upper"),
    ("lsmhe-N", lambda d: LeastSquaresMHE(1.0, d["model"].Phi, d["model"].W, d["C3"], np.zeros(6), N=0),
     ArgumentError, r"^LeastSquaresMHE: N must be >= 1, got 0"),
    ("ldf-omega", lambda d: LDF(np.array([1.0, -2.0, 3.0]), 0.9, n_pos=3, dt=DT), ArgumentError,
     r"^LDF: omega must be positive and finite, got -2 at index 1"),
    ("initial-error-std", lambda d: InitialError(kf(d), -0.1), ArgumentError, r"^InitialError: std must be >= 0"),
    ("wrapper-inner", lambda d: FromTruth("kf"), ArgumentTypeError, r"^FromTruth: inner must be an estimator \(init and step\), got str"),
    # sensors and actuators
    ("whitenoise-std-neg", lambda d: WhiteNoise(-0.1), ArgumentError, r"^WhiteNoise: std must be >= 0"),
    ("whitenoise-std-matrix", lambda d: WhiteNoise(np.ones((2, 2))), ArgumentError,
     r"^WhiteNoise: std must be a scalar or a vector"),
    ("linsensor-white-std", lambda d: LinearSensor(d["C3"], DT, white_std=np.ones(4)), ArgumentError,
     r"^LinearSensor: white_std must be a scalar or \(3,\)"),
    ("linsensor-gm-tau", lambda d: LinearSensor(d["C3"], DT, gm_tau=0.0), ArgumentError,
     r"^LinearSensor: gm_tau must be positive"),
    ("linsensor-quantum", lambda d: LinearSensor(d["C3"], DT, quantum=-1e-3), ArgumentError,
     r"^LinearSensor: quantum must be >= 0"),
    ("linsensor-dt", lambda d: LinearSensor(d["C3"], 0.0), ArgumentError, r"^LinearSensor: dt must be positive"),
    ("linsensor-C-ndim", lambda d: LinearSensor(np.ones((2, 3, 6)), DT), ArgumentError,
     r"^LinearSensor: C must be a \(p, n\) output matrix"),
    ("saturation-order", lambda d: Saturation(1.0, -1.0), ArgumentError, r"^Saturation: u_min must be <= u_max"),
    ("deadzone-order", lambda d: Deadzone(0.1, -0.1), ArgumentError, r"^Deadzone: d_minus must be <= d_plus"),
    ("disturbance-neg", lambda d: InputDisturbance(offset_std=-1.0), ArgumentError,
     r"^InputDisturbance: offset_std must be >= 0"),
    ("disturbance-shape", lambda d: InputDisturbance(white_std=np.ones(2), m=1), ArgumentError,
     r"^InputDisturbance: white_std must be a scalar or \(1,\)"),
    # controllers
    ("feedback-K-ndim", lambda d: jd.control.StateFeedback(np.ones((1, 1, 6))), ArgumentError,
     r"^StateFeedback: K must be an \(m, n\) gain"),
    ("feedback-x-ref", lambda d: jd.control.StateFeedback(d["K"], x_ref=np.zeros(4)), ArgumentError,
     r"^StateFeedback: x_ref must be \(6,\)"),
    ("feedback-K-nan", lambda d: jd.control.StateFeedback(np.full((1, 6), np.nan)), ArgumentError,
     r"^StateFeedback: K must be finite"),
    ("feedback-K-dtype", lambda d: jd.control.StateFeedback("K"), ArgumentTypeError,
     r"^StateFeedback: K must be real numbers"),
    ("satfeedback-order", lambda d: jd.control.SaturatedFeedback(d["K"], 5.0, -5.0), ArgumentError,
     r"^SaturatedFeedback: u_min must be <= u_max"),
    ("powerseries-P", lambda d: jd.control.PowerSeries(np.eye(4), d["A"], d["B"], np.eye(1), d["plant"]),
     ArgumentError, r"^PowerSeries: P must be \(6, 6\) for the plant DIP"),
    # plants
    ("dip-mass", lambda d: jd.plants.DIP(M1=-0.1), ArgumentError, r"^DIP: M1 must be positive and finite, got -0.1"),
    ("dip-variant", lambda d: jd.plants.DIP(variant="exact"), ArgumentError, r"^DIP: variant must be one of"),
    ("dip-damping", lambda d: jd.plants.DIP(Bc=-1.0), ArgumentError, r"^DIP: Bc must be >= 0"),
    ("rwp-inertia", lambda d: jd.plants.RWP(Jr=0.0), ArgumentError, r"^RWP: Jr must be positive"),
    ("twip-radius", lambda d: jd.plants.TWIP(r=np.nan), ArgumentError, r"^TWIP: r must be positive"),
    ("lorenz-rho", lambda d: jd.plants.Lorenz(rho=np.inf), ArgumentError, r"^Lorenz: rho must be finite"),
    # Riccati / LQR (python-control's calling convention)
    ("lqr-Q-shape", lambda d: jd.control.lqr(d["A"], d["B"], np.eye(4), np.eye(1)), ArgumentError,
     r"^lqr: Q must be \(6, 6\) for a 6-state model \(A is \(6, 6\)\), got \(4, 4\)$"),
    ("lqr-B-rows", lambda d: jd.control.lqr(d["A"], np.ones((4, 1)), np.eye(6), np.eye(1)), ArgumentError,
     r"^lqr: B must be \(6, \*\) for a 6-state model"),
    ("lqr-A-square", lambda d: jd.control.lqr(np.ones((6, 5)), d["B"], np.eye(6), np.eye(1)), ArgumentError,
     r"^lqr: A must be a square matrix, got \(6, 5\)"),
    ("lqr-R-shape", lambda d: jd.control.lqr(d["A"], d["B"], np.eye(6), np.eye(2)), ArgumentError,
     r"^lqr: R must be \(1, 1\) for 1 input \(B is \(6, 1\)\), got \(2, 2\)$"),
    ("lqr-A-dtype", lambda d: jd.control.lqr("A", d["B"], np.eye(6), np.eye(1)), ArgumentTypeError,
     r"^lqr: A must be real numbers"),
    ("dlqr-Q-psd", lambda d: jd.control.dlqr(d["model"].Phi, d["model"].W, NOT_PSD, np.eye(1)), ArgumentError,
     r"^dlqr: Q must be symmetric positive semidefinite"),
    ("care-checked-shape", lambda d: jd.control.care_checked(d["A"], d["B"], np.eye(6), np.eye(3)), ArgumentError,
     r"^care_checked: R must be \(1, 1\)"),
    ("lyap-Q", lambda d: jd.control.lyap(d["A"], np.eye(4)), ArgumentError,
     r"^lyap: Q must be \(6, 6\) for a 6-state model \(A is \(6, 6\)\), got \(4, 4\)"),
    # discretisation and linearisation
    ("zoh-h", lambda d: jd.zoh(d["A"], d["B"], -0.01), ArgumentError, r"^zoh: h must be positive"),
    ("zoh-B", lambda d: jd.zoh(d["A"], np.ones((4, 1)), DT), ArgumentError, r"^zoh: B must be \(6, m\) or \(6,\)"),
    ("zoh-A", lambda d: jd.zoh(np.ones((2, 3)), np.ones((2, 1)), DT), ArgumentError, r"^zoh: A must be a square matrix"),
    ("linearize-x", lambda d: jd.linearize(d["plant"], x=np.zeros(4)), ArgumentError,
     r"^linearize: x must be \(6,\) for DIP \(6 states\), got \(4,\)"),
    ("linearize-plant", lambda d: jd.linearize(lambda x, u: x), ArgumentTypeError,
     r"^linearize: plant must be a jaxdip Plant, got function"),
    # metrics
    ("metric-of", lambda d: jd.metrics.RMS("xhats"), ArgumentError, r"^RMS: of must be a Sample field"),
    ("metric-window", lambda d: jd.metrics.Window(jd.metrics.MaxAbs("x"), start=10, stop=5), ArgumentError,
     r"^Window: stop must be > start=10"),
    ("metric-band", lambda d: jd.metrics.TimeToBand("x", band=-1.0), ArgumentError, r"^TimeToBand: band must be >= 0"),
]


@pytest.mark.parametrize("build, exc, match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_wrong_argument_raises_one_named_error_before_tracing(dip, no_trace, build, exc, match):
    with pytest.raises(exc, match=match) as info:
        build(dip)
    assert isinstance(info.value, ValueError)  # one family: ArgumentTypeError is a ValueError as well
    assert "\n" not in str(info.value)


def test_a_dtype_error_is_also_a_type_error(dip, no_trace):
    with pytest.raises(TypeError, match="KalmanFilter: R"):
        kf(dip, R="diag")


def test_r_not_positive_definite_is_both_an_argument_and_a_riccati_error(dip, no_trace):
    """python-control users catch LinAlgError (tests/test_lqr.py keeps that); the message names lqr and R."""
    with pytest.raises(RiccatiError, match=r"^lqr: R must be symmetric positive definite.*R is not positive definite"):
        jd.control.lqr(dip["A"], dip["B"], np.eye(6), np.zeros((1, 1)))
    with pytest.raises(ArgumentError, match=r"^dlqr: R must be symmetric positive definite"):
        jd.control.dlqr(dip["model"].Phi, dip["model"].W, np.eye(6), -np.eye(1))


def test_the_guard_catches_a_trace(dip, no_trace):
    """The guard itself: a loop that is run (not just built) does reach the forbidden scan."""
    with pytest.raises(AssertionError, match="scan was called"):
        jd.simulate(loop(dip), np.zeros(6), jax.random.PRNGKey(0), 3)


def test_checks_do_not_change_numbers(dip):
    """A component built after its checks holds exactly the numbers it was given."""
    Q = np.diag(np.arange(1.0, 7.0)) * 1e-6
    f = kf(dip, Q=Q)
    np.testing.assert_array_equal(np.asarray(f.Q), Q)
    np.testing.assert_array_equal(np.asarray(f.Phi), np.asarray(dip["model"].Phi))
