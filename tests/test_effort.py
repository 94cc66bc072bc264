"""Compile effort (jaxdip.engine.effort): each level compiles its own program, levels agree with each other and
with an independent reference, a call under an enclosing trace still works, and the CLI records the level."""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxdip.cli import main
from jaxdip.engine import effort
from conftest import TINY_DIP_LQR


def _pendulum(x0, h, steps):
    """RK4 on the pendulum x'' = -sin x: written once for JAX (a scan) and once for NumPy (a loop)."""

    def f(x):
        return jnp.stack([x[1], -jnp.sin(x[0])])

    def step(x, _):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), None

    return jax.lax.scan(step, x0, None, length=steps)[0]


def _pendulum_numpy(x0, h, steps):
    def f(x):
        return np.array([x[1], -np.sin(x[0])])

    x = np.array(x0, dtype=float)
    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def test_each_level_compiles_its_own_program_and_all_agree_with_numpy():
    compiled = []

    def listen(ev, d, **kw):
        if ev.endswith("backend_compile_duration"):
            compiled.append(kw.get("fun_name"))

    run = effort.jit(_pendulum, static_argnums=2)
    x0 = jnp.array([2.0, 0.0])
    ref = _pendulum_numpy([2.0, 0.0], 0.01, 500)
    out = {}
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        for level in ("fast", "balanced", "full", "fast"):
            with effort.effort(level):
                assert effort.current() == level
                out[level] = np.asarray(run(x0, 0.01, 500))
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    # three levels, three programs; the second "fast" call reuses the first
    assert compiled.count("jit(_pendulum)") == 3, compiled
    for level, x in out.items():
        np.testing.assert_allclose(x, ref, rtol=1e-12, atol=1e-12, err_msg=level)


def test_a_call_inside_an_enclosing_jit_is_inlined_at_any_level():
    inner = effort.jit(lambda x: jnp.sin(x) * 2.0)
    outer = jax.jit(lambda x: inner(x) + inner(jnp.float64(1.0)))  # the second call has no traced argument
    with effort.effort("fast"):
        np.testing.assert_allclose(float(outer(jnp.float64(0.5))), 2 * np.sin(0.5) + 2 * np.sin(1.0), rtol=1e-14)
        # differentiated and vmapped from outside: the call sees tracers and compiles nothing itself
        g = jax.grad(lambda x: inner(x))(jnp.float64(0.3))
        np.testing.assert_allclose(float(g), 2 * np.cos(0.3), rtol=1e-14)


def test_unknown_level_is_refused():
    with pytest.raises(ValueError, match="compile effort"):
        with effort.effort("fastest"):
            pass
    with pytest.raises(ValueError, match="compile effort"):
        effort.set_default("O0")


def test_process_level_sets_xla_flags_once_and_keeps_the_users():
    import subprocess
    import sys

    script = (
        "import os; from jaxdip.engine import effort\n"
        "effort.set_process_level('balanced'); effort.set_process_level('fast')\n"
        "print(os.environ['XLA_FLAGS'])\n"
        "import jax.numpy as jnp; float(jnp.ones(2).sum())\n"
        "effort.set_process_level('balanced')  # every option already there: nothing to do\n"
        "os.environ['XLA_FLAGS'] = ''\n"
        "try:\n    effort.set_process_level('fast')\nexcept RuntimeError:\n    print('refused after start')\n")
    env = dict(os.environ, XLA_FLAGS="--xla_cpu_use_fusion_emitters=true")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    flags, refused = out.stdout.strip().splitlines()
    # the user's emitter choice stays; the first call's level is added once, the second call finds it there
    assert flags.split() == ["--xla_cpu_use_fusion_emitters=true", "--xla_backend_optimization_level=1"]
    assert refused == "refused after start"
    effort.set_process_level("full")  # no options at all: never refused


def test_cli_records_the_level_and_levels_agree(tmp_path):
    outs = {}
    for level in ("fast", "full"):
        out = tmp_path / level
        assert main([*TINY_DIP_LQR, "--out", str(out), "--compile-effort", level]) == 0
        outs[level] = json.load(open(os.path.join(out, "metrics.json")))
        assert outs[level]["compile_effort"] == level
    a, b = outs["fast"]["results"], outs["full"]["results"]
    flat_a, flat_b = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(flat_a) == len(flat_b) > 0
    for u, v in zip(flat_a, flat_b):
        if isinstance(u, float):
            assert u == pytest.approx(v, rel=1e-9, abs=1e-14)
        else:
            assert u == v
    # without the flag a quick run takes the experiment's measured quick level
    assert main([*TINY_DIP_LQR, "--out", str(tmp_path / "default")]) == 0
    assert json.load(open(tmp_path / "default" / "metrics.json"))["compile_effort"] == "fast"
