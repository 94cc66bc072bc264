"""The config keys added for the fidelity readings of Aranovskiy Fig. 3 and thesis §2.7.2, each against an
independent reference: the Luenberger gain set by ``luenberger_omega`` against the characteristic polynomial of
its error dynamics (numpy.poly), ``observer_current`` against the clip it stands for, and the ensemble search's
``final = "best_member"`` and ``x0_draw = "per_member"`` against plain Python loops over the performance map."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from experiments.fidelity import twip as T
from experiments.fidelity import twip_pages
from jaxdip import config as C
from jaxdip.estimators import homd
from jaxdip.estimators import luenberger as lu
import experiments.eki_examples as E
import experiments.rwp_bias as R
from jaxdip.scenarios import rwp as S
from jaxdip.search.p_search import direction_search, lowest_y1


def test_luenberger_omega_sets_the_error_dynamics():
    cfg = C.from_dict(R.RwpBiasConfig, {"luenberger_omega": [2.0, 7.0]})
    prm, wp, wr = R.luenberger_parameters(cfg)
    assert (wp, wr) == (2.0, 7.0)
    A, _, Cm = (np.asarray(m) for m in lu.full_linear_model(prm.model))
    Err = A - np.asarray(prm.L) @ Cm
    np.testing.assert_allclose(Err[:2, 2:], 0, atol=1e-12)
    np.testing.assert_allclose(Err[2:, :2], 0, atol=1e-12)
    # Table 2: k1 = 5, k2 = 12 for both differentiators; gains (omega k1, omega^2 k2)
    for blk, w in ((Err[:2, :2], 2.0), (Err[2:, 2:], 7.0)):
        np.testing.assert_allclose(np.poly(blk), [1, 5 * w, 12 * w**2], rtol=1e-12)
    # empty (the default) keeps the rise-time matching
    d = R.luenberger_parameters(C.from_dict(R.RwpBiasConfig, {}))
    assert d[1] != 2.0 and abs(d[1] - 1.287) < 0.01
    with pytest.raises(C.ConfigError):
        C.from_dict(R.RwpBiasConfig, {"luenberger_omega": [1.0]})
    with pytest.raises(C.ConfigError):
        C.from_dict(R.RwpBiasConfig, {"luenberger_omega": [1.0, -1.0]})
    with pytest.raises(C.ConfigError):
        C.from_dict(R.RwpBiasConfig, {"observer_current": "both"})


def _currents(observer_current, limit=3.0, steps=200):
    est = homd.HOMDObserver.build(0.002, substeps=2)
    lp = S.loop(est, dt=0.002, substeps=2, current_limit=limit, observer_current=observer_current)
    sol = jd.simulate(lp, jnp.array([0.1, 0.0, 0.0, 0.0]), jax.random.PRNGKey(0), steps,
                      save=lambda s: jnp.stack([s.u[0], s.u_applied[0], s.xhat[1]]))
    return np.asarray(sol.saved)


def test_observer_current_is_the_clipped_current_when_applied():
    """The estimator is given u_{k-1} = the controller's output: with "applied" the clip sits in the controller
    (u = clip(-K xhat) = what the plant gets), with "commanded" only the plant's input is clipped."""
    lim = 3.0
    a = _currents("applied", lim)
    assert np.abs(a[:, 0]).max() <= lim and np.abs(a[:, 0]).max() == pytest.approx(lim)
    np.testing.assert_array_equal(a[:, 0], a[:, 1])
    c = _currents("commanded", lim)
    assert np.abs(c[:, 0]).max() > 10 * lim  # the law asks for ~58 A at theta = 0.1
    np.testing.assert_array_equal(c[:, 1], np.clip(c[:, 0], -lim, lim))
    # the observers' models see different currents, so their velocity estimates part
    assert np.abs(a[:, 2] - c[:, 2]).max() > 1e-3


def _nl(**kw):
    base = {"ensemble": 6, "iterations": 5, "K": 4, "select_states": 5}
    return C.from_dict(E.EkiNonlinearConfig, {**base, **kw})


def test_lowest_y1_matches_a_python_loop():
    cfg = _nl()
    eki = E.make_eki(cfg)
    ang = np.linspace(0.1, 3.0, 7)
    vs = jnp.asarray(np.stack([np.cos(ang), np.sin(ang)], 1))
    key = jax.random.PRNGKey(3)
    keys = jax.random.split(key, 9)
    G = jax.jit(eki.G)  # one program for the 63 evaluations (eager, each one traced and compiled its loop anew)
    scores = [np.mean([float(G(vs[i], k)[0]) for k in keys]) for i in range(len(ang))]
    got = np.asarray(lowest_y1(eki, vs, key, 9))
    np.testing.assert_array_equal(got, np.asarray(vs[int(np.argmin(scores))]))


def test_best_member_ends_with_the_best_final_member():
    """final = "best_member": the search returns the member (normalised) with the lowest mean y1 over the
    selection states. With no iterations the final ensemble is the initial draw, which the test rebuilds, so the
    selection is checked exactly (after updates the EKI amplifies last-bit differences between programs)."""
    eki = E.make_eki(_nl())
    key = jax.random.PRNGKey(11)
    n, sel_n = 6, 5
    v, _ = direction_search(eki, key, ensemble=n, init_var=0.2, iterations=0, select_states=sel_n,
                            final="best_member")
    k_init, _ = jax.random.split(key)
    m0 = np.asarray(jnp.sqrt(0.2) * jax.random.normal(k_init, (n, 2)))
    members = m0 / np.linalg.norm(m0, axis=1, keepdims=True)
    sel = jax.random.split(jax.random.fold_in(key, 2), sel_n)
    G = jax.jit(eki.G)
    scores = [np.mean([float(G(jnp.asarray(m), k)[0]) for k in sel]) for m in members]
    best = members[int(np.argmin(scores))]
    # the ensemble is sign-aligned on entry (P_v(v) = P_v(-v)): the same member up to its sign
    sign = np.sign(np.asarray(v) @ best)
    np.testing.assert_allclose(sign * np.asarray(v), best, rtol=1e-12, atol=1e-14)
    mean, _ = direction_search(eki, key, ensemble=n, init_var=0.2, iterations=0, select_states=sel_n)
    assert np.min(np.abs(members @ np.asarray(mean))) < 1 - 1e-6  # the mean is not a member: the options differ
    with pytest.raises(ValueError):
        direction_search(eki, key, ensemble=4, init_var=0.2, iterations=1, final="median")


def test_x0_per_member_evaluates_each_member_on_its_own_draw():
    cfg = _nl(x0_draw="per_member")
    eki = E.make_eki(cfg)
    assert eki.member_keys and not E.make_eki(_nl()).member_keys
    vs = jnp.asarray([[1.0, 0.0], [0.0, 1.0], [0.6, 0.8]])
    st = eki.init(vs, jax.random.PRNGKey(0))
    key = jax.random.PRNGKey(5)
    Y = np.asarray(eki.evaluate(st, key))
    flat = np.asarray(st.members)
    ref = np.stack([np.asarray(eki.G(jnp.asarray(flat[j]), jax.random.fold_in(key, j))) for j in range(3)])
    np.testing.assert_array_equal(Y, ref)
    with pytest.raises(C.ConfigError):
        _nl(x0_draw="each")
    with pytest.raises(C.ConfigError):
        _nl(final="best")


def test_partial_twip_run_keeps_the_other_parts():
    """python -m experiments.fidelity.twip --only <some parts>: the other parts' rows and page text survive unchanged, the parts
    run replace their own sections (marked, or by heading on an older page) and rows; a run of every part keeps
    no old row."""
    old_rows = [{"claim": "stumfoll:table-8.3-param-lqr", "reading": "a"},
                {"claim": "stumfoll:fig-8.18", "reading": "old"},
                {"claim": "stumfoll:fig-8.13", "reading": "b"}]
    new_rows = [{"claim": "stumfoll:fig-8.18", "reading": "new"}]
    kept = T._kept_rows(old_rows, ["fig_8_18"], new_rows)
    assert kept == [old_rows[0], old_rows[2]]
    assert T._kept_rows(old_rows, list(T.PARTS), new_rows) == []
    # a page from before the markers: its '## ' sections are kept, except those a part run now writes again
    old_page = ("# head\n\nintro\n\n## A\n\nold a\n\n## B\n\nold b\n\n"
                "<!-- part: fig_8_18 -->\n## F\nold section\n<!-- end part: fig_8_18 -->\n")
    page = twip_pages.page(old_page, ["# fresh head", ""], {"fig_8_18": ["## F", "new section"]}, ["table_8_3", "fig_8_18"])
    assert "old a" in page and "old b" in page and "new section" in page and "old section" not in page
    assert page.count("# fresh head") == 1 and "# head" not in page and page.count("## F") == 1
    page2 = twip_pages.page(old_page, ["# fresh head", ""], {"table_8_3": ["## B", "new b"]}, ["table_8_3", "fig_8_18"])
    assert "old a" in page2 and "old b" not in page2 and "new b" in page2 and "old section" in page2
    assert page2.count("## B") == 1 and page2.index("new b") < page2.index("old section")
    # the next run of that part replaces its (now marked) section again
    page3 = twip_pages.page(page2, ["# fresh head", ""], {"table_8_3": ["## B", "newer b"]}, ["table_8_3", "fig_8_18"])
    assert "new b" not in page3 and "newer b" in page3 and "old a" in page3 and "old section" in page3
