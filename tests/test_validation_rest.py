"""Argument checks of the components issue 38's first pass left: the TWIP extra control, the RWP's HOMD, bias and
Luenberger observers, the backlash sensor and actuator, ``metrics.Window``, ``FunctionPlant``, ``jd.summary`` and
``param()``'s converter (a string where a number goes). Each case asserts one ``ArgumentError`` whose message
names the class (or function) and the argument, raised with JAX's tracing entry points forbidden (the ``no_trace``
guard of tests/test_validation.py). Then no false alarms: the normal builds, a traced gain, and the CLI's one line
for a config value that passes the config's checks but not a component's.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip.control.extra_control import ExtraControl
from jaxdip.control.twip_lqr import twip_dlqr
from jaxdip.engine.checks import ArgumentError, ArgumentTypeError
from jaxdip.engine.function_plant import FunctionPlant
from jaxdip.engine.metrics import RMS, Window
from jaxdip.estimators import bias_observers as bo
from jaxdip.estimators import homd
from jaxdip.estimators import luenberger as lu
from jaxdip.plants import rwp, twip
from jaxdip.sim.actuators import InputBacklash, OutputBacklash, Saturation
from tests.test_validation import no_trace  # noqa: F401  (fixture)

DT = 0.002


@pytest.fixture(scope="module")
def parts():
    d = twip_dlqr(twip.TWIP(), dt=0.01)
    hp = homd.HOMDObserver.build(DT)
    return dict(K=np.asarray(d.K), A=np.asarray(d.A), B=np.asarray(d.B), ec=ExtraControl.design(d.K, d.A, d.B),
                hp=hp)


def ec(p, **kw):
    args = {"K": p["K"], "A": p["A"], "B": p["B"], **kw}
    return ExtraControl.design(**args)


def cart(x, u):
    return jnp.stack([x[1], u[0]])


def fp(**kw):
    return FunctionPlant(**{**dict(fn=cart, state_names=("x", "v"), input_names=("F",)), **kw})


E3 = {"e": np.ones((3, 2))}  # three seeds of a two-entry metric

# (id, build(parts), exception, match): ``match`` names the owner and the argument
CASES = [
    # ExtraControl.design and the controller's fields
    ("ec-K", lambda p: ec(p, K=np.ones((1, 6))), ArgumentError,
     r"^ExtraControl: K must be \(1, 4\) \(the 4-state TWIP model \(79\)\), got \(1, 6\)$"),
    ("ec-A", lambda p: ec(p, A=np.eye(3)), ArgumentError, r"^ExtraControl: A must be \(4, 4\)"),
    ("ec-B", lambda p: ec(p, B=np.ones((4, 2))), ArgumentError, r"^ExtraControl: B must be \(4, 1\)"),
    ("ec-virtual", lambda p: ec(p, virtual="flatt"), ArgumentError,
     r"^ExtraControl: virtual must be one of \('printed', 'effective', 'flat'\), got 'flatt'$"),
    ("ec-k1", lambda p: ec(p, k1=-1.0), ArgumentError, r"^ExtraControl: k1 must be >= 0 and finite, got -1$"),
    ("ec-dt", lambda p: ec(p, dt=0.0), ArgumentError, r"^ExtraControl: dt must be positive and finite, got 0$"),
    ("ec-u_max", lambda p: ec(p, u_max=-1.0), ArgumentError, r"^ExtraControl: u_max must be positive"),
    ("ec-tau_d", lambda p: ec(p, tau_d=-0.05), ArgumentError, r"^ExtraControl: tau_d must be >= 0"),
    ("ec-gamma-nan", lambda p: ec(p, gamma=np.nan), ArgumentError, r"^ExtraControl: gamma11 must be finite"),
    ("ec-n_hidden", lambda p: ec(p, n_hidden=0), ArgumentError, r"^ExtraControl: n_hidden must be >= 1, got 0$"),
    ("ec-gamma-str", lambda p: ec(p, gamma="fast"), ArgumentTypeError,
     r"^ExtraControl: gamma must be real numbers, got 'fast'$"),
    ("ec-gamma-vector", lambda p: ec(p, gamma=[0.1, 0.1]), ArgumentError, r"^ExtraControl: gamma must be a scalar"),
    ("ec-b1-shape", lambda p: dataclasses.replace(p["ec"], b1=np.ones(5)), ArgumentError,
     r"^ExtraControl: b1 must be \(10,\) \(n_hidden=10\), got \(5,\)$"),
    ("ec-B2-zero", lambda p: dataclasses.replace(p["ec"], B2=0.0), ArgumentError,
     r"^ExtraControl: B2 must be nonzero \(it is inverted in \(101\)\), got 0$"),
    ("ec-field-str", lambda p: dataclasses.replace(p["ec"], sigma21="small"), ArgumentTypeError,
     r"^ExtraControl: sigma21 must be real numbers, got 'small'$"),
    # HOMD, bias and Luenberger observers of the RWP
    ("homd-pend-len", lambda p: homd.HOMDObserver.build(DT, pend=(5.0, 12.0)), ArgumentError,
     r"^HOMDObserver: pend must be the three gains \(k1, k2, alpha\), got \(5.0, 12.0\)$"),
    ("homd-alpha", lambda p: homd.HOMDObserver.build(DT, pend=(5.0, 12.0, 0.3)), ArgumentError,
     r"^HOMDObserver: pend.alpha must be in \(0.5, 1\], got 0.3$"),
    ("homd-k1", lambda p: homd.HOMDObserver.build(DT, wheel=(-5.0, 12.0, 0.9)), ArgumentError,
     r"^HOMDObserver: wheel.k1 must be positive and finite, got -5$"),
    ("homd-str", lambda p: homd.HOMDObserver.build(DT, wheel=("5", 12.0, 0.9)), ArgumentTypeError,
     r"^HOMDObserver: wheel.k1 must be real numbers"),
    ("homd-model", lambda p: homd.HOMDObserver.build(DT, model=twip.TWIP()), ArgumentTypeError,
     r"^HOMDObserver: model must be an RWP .*, got TWIP$"),
    ("lowpass-gamma", lambda p: bo.LowpassHOMD.build(p["hp"], gamma_d=-0.05), ArgumentError,
     r"^LowpassHOMD: gamma_d must be >= 0 and finite, got -0.05$"),
    ("lowpass-vector", lambda p: bo.LowpassHOMD.build(p["hp"], gamma_d=[0.05, 0.5]), ArgumentError,
     r"^LowpassHOMD: gamma_d must be a scalar, got shape \(2,\)$"),
    ("lowpass-h", lambda p: bo.LowpassHOMD.build(DT), ArgumentTypeError,
     r"^LowpassHOMD: h must be a HOMDObserver .*, got float$"),
    ("measured-d0", lambda p: bo.LowpassMeasured.build(DT, d0=np.nan), ArgumentError,
     r"^LowpassMeasured: d0 must be finite, got nan$"),
    ("measured-str", lambda p: bo.LowpassMeasured.build(DT, gamma_d="0.05"), ArgumentTypeError,
     r"^LowpassMeasured: gamma_d must be a number, got '0.05'$"),
    ("reduced-L0", lambda p: bo.ReducedOrderMeasured.build(DT, None, L0=0.0), ArgumentError,
     r"^ReducedOrderMeasured: L0 must be positive and finite, got 0$"),
    ("joint-L0", lambda p: bo.JointObserver.build(p["hp"], L0=-0.01), ArgumentError,
     r"^JointObserver: L0 must be positive and finite, got -0.01$"),
    ("luenberger-L", lambda p: lu.LuenbergerObserver.build(DT, np.ones((4, 4))), ArgumentError,
     r"^LuenbergerObserver: L must be \(4, 2\) \(4 observer states, 2 measurements"),
    ("luenberger-str", lambda p: lu.LuenbergerObserver.build(DT, "L"), ArgumentTypeError,
     r"^LuenbergerObserver: L must be real numbers, got 'L'$"),
    # backlash
    ("inbacklash-m", lambda p: InputBacklash(0.0), ArgumentError, r"^InputBacklash: m must be positive"),
    ("inbacklash-band", lambda p: InputBacklash(1.0, 0.1, -0.1), ArgumentError,
     r"^InputBacklash: d_minus must be <= d_plus"),
    ("inbacklash-shapes", lambda p: InputBacklash(np.ones(2), np.zeros(3), np.zeros(3)), ArgumentError,
     r"^InputBacklash: m must be a scalar or have the shape of d_minus \(3,\), got \(2,\)$"),
    ("outbacklash-law", lambda p: OutputBacklash(law="printd"), ArgumentError,
     r"^OutputBacklash: law must be one of \('standard', 'printed'\), got 'printd'$"),
    ("outbacklash-vector", lambda p: OutputBacklash(1.0, -np.ones(2), np.ones(2)), ArgumentError,
     r"^OutputBacklash: d_minus must be a scalar or \(1,\) \(the one channel 2\), got shape \(2,\)$"),
    ("outbacklash-channel", lambda p: OutputBacklash(channel=-1), ArgumentError,
     r"^OutputBacklash: channel must be >= 0, got -1$"),
    # metrics.Window
    ("window-stop", lambda p: Window(RMS("x"), start=5, stop=5), ArgumentError,
     r"^Window: stop must be > start=5 \(or None: to the end\), got 5$"),
    ("window-start-type", lambda p: Window(RMS("x"), start=1.5), ArgumentTypeError,
     r"^Window: start must be an integer, got 1.5$"),
    ("window-stop-type", lambda p: Window(RMS("x"), stop="end"), ArgumentTypeError,
     r"^Window: stop must be an integer, got 'end'$"),
    # FunctionPlant
    ("fp-fn", lambda p: fp(fn="cart"), ArgumentTypeError, r"^FunctionPlant: fn must be a function f\(x, u\), got str$"),
    ("fp-empty-name", lambda p: fp(state_names=("x", "")), ArgumentError,
     r"^FunctionPlant: state_names must be non-empty strings, got \('x', ''\)$"),
    ("fp-repeated", lambda p: fp(state_names=("x", "x")), ArgumentError,
     r"^FunctionPlant: state_names must be distinct, one per state, got \('x', 'x'\) \(x repeated\)$"),
    ("fp-no-inputs", lambda p: fp(input_names=()), ArgumentError,
     r"^FunctionPlant: input_names must name at least one input, got \(\)$"),
    ("fp-number-names", lambda p: fp(state_names=2), ArgumentTypeError,
     r"^FunctionPlant: state_names must be a string or a sequence of strings, got 2$"),
    ("fp-name-types", lambda p: fp(state_names=("x", 1)), ArgumentTypeError,
     r"^FunctionPlant: state_names must be strings"),
    ("fp-params", lambda p: fp(fn=lambda x, u, q: x, params={"l": "long"}), ArgumentTypeError,
     r"^FunctionPlant: params\['l'\] must be real numbers, got 'long'$"),
    ("fp-discrete", lambda p: fp(discrete="yes"), ArgumentTypeError,
     r"^FunctionPlant: discrete must be True or False, got 'yes'$"),
    # jd.summary
    ("summary-level", lambda p: jd.summary(E3, level=95), ArgumentError,
     r"^summary: level must be a number in \(0, 1\) \(0.95: a 95% interval\), got 95$"),
    ("summary-axis", lambda p: jd.summary(E3, axis=2), ArgumentError,
     r"^summary: metric 'e' must have a seeds axis 2 \(a Monte Carlo result\), got shape \(3, 2\)$"),
    ("summary-axis-type", lambda p: jd.summary(E3, axis="seeds"), ArgumentTypeError,
     r"^summary: axis must be an integer, got 'seeds'$"),
    ("summary-names", lambda p: jd.summary(E3, names=5), ArgumentTypeError, r"^summary: names must be a plant"),
    ("summary-strings", lambda p: jd.summary({"e": np.array(["a", "b"])}), ArgumentTypeError,
     r"^summary: metric 'e' must be real numbers"),
    ("summary-result", lambda p: jd.summary(E3, result=np.zeros(4, np.int32)), ArgumentError,
     r"^summary: result must have 3 seeds along axis 0, got shape \(4,\)$"),
    # param(): a string or a complex number where a number goes, named by the class that declares the field
    ("param-str", lambda p: twip.TWIP(Mp="heavy"), ArgumentTypeError, r"^TWIP: Mp must be real numbers, got 'heavy'$"),
    ("param-inherited", lambda p: twip.TWIPUnmodeled(Mp="heavy"), ArgumentTypeError,
     r"^TWIP: Mp must be real numbers, got 'heavy'$"),
    ("param-complex", lambda p: Saturation(-1.0, 1.0 + 2j), ArgumentTypeError,
     r"^Saturation: u_max must be real numbers, got complex128$"),
    ("param-object", lambda p: rwp.RWP(k=object()), ArgumentTypeError, r"^RWP: k must be real numbers, got .*object"),
]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_wrong_argument_raises_one_named_error_before_tracing(parts, no_trace, case):  # noqa: F811
    _, build, exc, match = case
    with pytest.raises(exc, match=match) as info:
        build(parts)
    assert type(info.value) in (ArgumentError, ArgumentTypeError)


def test_the_normal_builds_raise_nothing(parts, no_trace):  # noqa: F811
    hp = parts["hp"]
    assert ec(parts, virtual="flat", gamma=0.0, u_max=np.inf, K=parts["K"].ravel()).K.shape == (1, 4)
    assert dataclasses.replace(parts["ec"], B2=2.0).B2 == 2.0
    L = np.ones((4, 2))
    built = [bo.LowpassHOMD.build(hp, 0.05, 0.0), bo.JointObserver.build(hp, 0.01),
             bo.LowpassMeasured.build(DT, 0.0, 0.1), bo.ReducedOrderMeasured.build(DT, None, 0.01),
             homd.HOMDObserver.build(DT, pend=homd.gains(5.0, 12.0, 1.0), wheel=[5, 12, 0.51]),
             lu.LuenbergerObserver.build(DT, L), InputBacklash(np.ones(1), -0.4 * np.ones(1), 0.4 * np.ones(1)),
             OutputBacklash(1.0, -0.01, 0.01, law="printed"), InputBacklash(), Window(RMS("x"), 0, 10),
             Window(RMS("x"), start=-40), fp(), fp(state_names="x", fn=lambda x, u: -x, discrete=True),
             fp(fn=lambda x, u, q: x, params={"l": 0.5, "n": np.arange(3)}), twip.TWIP(Mp=np.float32(2.0)),
             rwp.RWP(k=0)]
    assert all(b is not None for b in built)
    s = jd.summary(E3, ("a", "b"), level=0.9)
    np.testing.assert_allclose(s["e"]["b"].mean, 1.0)


def test_a_traced_gain_still_builds_and_differentiates(parts):
    # values are not checked on tracers: jax.grad through the gains is what it was without the checks
    def k1_of(k):
        return ec(parts, k1=k).k1 * 2.0

    assert float(jax.grad(k1_of)(2.5)) == 2.0
    L0s = jax.vmap(lambda v: bo.JointObserver.build(parts["hp"], v).L0)(jnp.array([0.01, 0.02]))
    np.testing.assert_allclose(L0s, [0.01, 0.02])
    alphas = jax.vmap(lambda a: homd.HOMDObserver.build(DT, pend=(5.0, 12.0, a)).pend.alpha)(jnp.array([0.6, 0.9]))
    np.testing.assert_allclose(alphas, [0.6, 0.9])


def test_param_converter_keeps_the_values(parts):
    # the converter only refuses: a valid value is stored exactly as before (float64 array)
    p = twip.TWIP(Mp=3, R=np.float32(0.5))
    assert p.Mp.dtype == jnp.float64 and float(p.Mp) == 3.0 and float(p.R) == np.float64(np.float32(0.5))


def test_cli_refuses_a_config_value_a_component_rejects_with_one_line(tmp_path, capsys):
    from jaxdip import cli

    out = tmp_path / "run"
    # k1 passes the config's own check (any finite number) but ExtraControl needs k1 >= 0
    code = cli.main(["run", "twip-extra-control", "--quick", "--out", str(out), "--set", "k1=-1"])
    err = capsys.readouterr().err
    assert code == 2
    assert err == "error: k1: ExtraControl: k1 must be >= 0 and finite, got -1\n"


def test_the_2d_examples_check_their_constants(no_trace):  # noqa: F811
    from jaxdip.plants import examples2d

    with pytest.raises(ArgumentError, match=r"^Linear: B must be \(2, 1\) \(2 states, 1 input\), got \(1, 2\)$"):
        examples2d.Linear(B=((0.1, 0.2),))
    with pytest.raises(ArgumentError, match=r"^Linear: A must be finite, got inf at index \(1, 1\)$"):
        examples2d.Linear(A=((1.0, 0.0), (0.0, np.inf)))
    with pytest.raises(ArgumentError, match=r"^Nonlinear: g0 must be a scalar, got shape \(2,\)$"):
        examples2d.Nonlinear(g0=(1.0, 2.0))
    with pytest.raises(ArgumentTypeError, match=r"^Nonlinear: w must be real numbers, got 'fast'$"):
        examples2d.Nonlinear(w="fast")
    assert examples2d.Linear().A.shape == (2, 2) and float(examples2d.Nonlinear(a=1).a) == 1.0


def test_extra_control_b_is_a_scalar_or_one_per_neuron(parts, no_trace):  # noqa: F811
    np.testing.assert_array_equal(ec(parts, n_hidden=3, b=[1.0, 2.0, 3.0]).b1, [1.0, 2.0, 3.0])
    msg = r"^ExtraControl: b must be a scalar or \(3,\) \(n_hidden=3\), got shape \(2,\)$"
    with pytest.raises(ArgumentError, match=msg):
        ec(parts, n_hidden=3, b=[1.0, 2.0])


def test_reproduce_refuses_a_component_error_with_one_line_naming_the_experiment(tmp_path, capsys, monkeypatch):
    from jaxdip import cli
    from jaxdip import config as C

    load = C.load

    def bad_k1(cls, *a, **kw):  # the default config with a k1 the config accepts and ExtraControl does not
        cfg = load(cls, *a, **kw)
        return dataclasses.replace(cfg, k1=-1.0) if hasattr(cfg, "k1") else cfg

    monkeypatch.setattr(C, "load", bad_k1)
    code = cli.main(["reproduce", "--only", "twip-extra-control", "--quick", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err.splitlines()
    assert code == 2
    assert err[-1] == "error: twip-extra-control: k1: ExtraControl: k1 must be >= 0 and finite, got -1"
