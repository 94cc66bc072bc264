"""jaxdip.theory.twip_transients: the open-loop swing against SciPy's DOP853, and the figures of merit against
plain definitions."""

import math

import numpy as np
from scipy.integrate import solve_ivp

from jaxdip.plants import twip
from jaxdip.theory import twip_transients as T


def test_swing_matches_dop853():
    t, x = T.swing(10.0, duration=3.0, dt=0.01, substeps=10)
    p = twip.TWIP()
    rhs = lambda _t, s: np.asarray(twip.f(p, s, np.zeros(1)))
    ref = solve_ivp(rhs, (0.0, 3.0), x[0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
    np.testing.assert_allclose(x, ref.y.T, atol=1e-9)
    assert abs(T.theta_of(x[0, 2]) - math.radians(10.0)) < 1e-12


def test_settling_time_and_overshoot_definitions():
    t = np.arange(10) * 0.5
    s = np.array([5.0, 3.0, -2.0, 0.5, -1.5, 0.2, 0.1, -0.3, 0.05, 0.0])
    # last sample outside |s| <= 1 is index 4 (-1.5): settled from t[5]
    assert T.settling_time(t, s, 1.0) == 2.5
    assert T.settling_time(t, s, 10.0) == 0.0
    assert T.settling_time(t, np.append(s[:-1], 3.0), 1.0) == math.inf
    assert T.overshoot(s) == 2.0  # starts above 0, goes down to -2
    assert T.overshoot(-s) == 2.0
    assert T.overshoot(np.array([3.0, 2.0, 1.0])) == 0.0
    assert list(T.peaks(np.array([0.0, 2.0, 0.0, -3.0, 0.0, 0.0]))) == [1, 3]


def test_reach_time_is_the_first_sample_with_every_column_inside():
    t = np.arange(5) * 1.0
    X = np.array([[3.0, 0.0], [0.5, 2.0], [0.2, 0.1], [2.0, 0.0], [0.0, 0.0]])
    assert T.reach_time(t, X, [1.0, 1.0]) == 2.0
    assert T.reach_time(t, X, [0.1, 0.1]) == 4.0
    assert T.reach_time(t, X, [0.01, 0.0]) == 4.0
    assert T.reach_time(t, X + 5.0, [1.0, 1.0]) == math.inf
