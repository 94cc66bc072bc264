"""Compile effort (jaxdip.xla_flags): one level per process, set in XLA_FLAGS before JAX starts. Every level's
program agrees with an independent NumPy reference, a user's own XLA_FLAGS stay, and the CLI applies, records
and refuses levels."""

import json
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from conftest import TINY_DIP_LQR, Child
from jaxdip import xla_flags
from jaxdip.cli import main

LEVEL_OPTIONS = ("xla_backend_optimization_level", "xla_cpu_use_fusion_emitters")


def _without_level() -> str:
    """This process's XLA_FLAGS less the compile effort's options (the suite's own level), for a child process."""
    return " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if not f[2:].startswith(LEVEL_OPTIONS))


def _pendulum(x0, h, steps):
    """RK4 on the pendulum x'' = -sin x: written once for JAX (a scan) and once for NumPy (a loop)."""
    import jax.numpy as jnp

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


_CHILD = """
import sys
import numpy as np
from jaxdip import xla_flags
xla_flags.set_effort(sys.argv[1])
import jax, jax.numpy as jnp
exec(sys.argv[2])
x = jax.jit(_pendulum, static_argnums=2)(jnp.array([2.0, 0.0]), 0.01, 500)
print(xla_flags.effort(), *np.asarray(x).tolist())
"""


def test_each_level_agrees_with_numpy():
    import inspect

    env = dict(os.environ, XLA_FLAGS=_without_level())
    procs = {level: subprocess.Popen([sys.executable, "-c", _CHILD, level, inspect.getsource(_pendulum)], env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for level in xla_flags.EFFORTS}
    ref = _pendulum_numpy([2.0, 0.0], 0.01, 500)
    for level, proc in procs.items():
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
        got, *x = out.split()
        assert got == level
        np.testing.assert_allclose(np.array(x, float), ref, rtol=1e-12, atol=1e-12, err_msg=level)


def test_unknown_level_is_refused(monkeypatch):
    with pytest.raises(ValueError, match="compile effort"):
        xla_flags.set_effort("fastest")
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=2")
    with pytest.raises(ValueError, match="none of the compile efforts"):
        xla_flags.effort()


def test_level_sets_xla_flags_once_and_keeps_the_users(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    xla_flags.set_effort("balanced")
    xla_flags.set_effort("fast")
    # the user's emitter choice stays; the first call's level is added once, the second call finds it there
    assert os.environ["XLA_FLAGS"].split() == ["--xla_cpu_use_fusion_emitters=true",
                                               "--xla_backend_optimization_level=1"]
    with pytest.raises(ValueError, match="none of the compile efforts"):  # a mix, not one of the levels: said so
        xla_flags.effort()
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    assert xla_flags.effort() == "full"
    xla_flags.set_effort("full")  # no options at all
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=2"
    xla_flags.set_effort("fast")
    assert xla_flags.effort() == "fast"


# full compiles the slowest of the three (4-5 s of the test's 13 s cold): with -m slow
@pytest.mark.parametrize("asked", ["fast", pytest.param("full", marks=pytest.mark.slow)])
def test_cli_applies_and_records_the_level_and_levels_agree(tmp_path, asked):
    env = dict(os.environ, XLA_FLAGS=_without_level(), JAXDIP_NO_PROGRESS="1")
    # on dip-lqr's float32 noise draw, `fast` rounds some normals one float32 ulp apart from the other levels, which
    # moves these results by about 1e-8 relative; the levels' agreement is checked on the float64 draw
    runs = {level: Child([*TINY_DIP_LQR, "--set", "noise_draw=loop", "--out", str(tmp_path / level)]
                         + (["--compile-effort", level] if level != "default" else []), env)
            for level in (asked, "default")}
    outs = {}
    for level, child in runs.items():
        assert child.returncode == 0, child.stderr
        outs[level] = json.load(open(tmp_path / level / "metrics.json"))
    assert outs[asked]["compile_effort"] == asked
    assert outs["default"]["compile_effort"] == "balanced"  # a quick run's level without the flag
    a, b = outs[asked]["results"], outs["default"]["results"]
    flat_a, flat_b = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    assert len(flat_a) == len(flat_b) > 0
    for u, v in zip(flat_a, flat_b):
        if isinstance(u, float):
            assert u == pytest.approx(v, rel=1e-9, abs=1e-14)
        else:
            assert u == v
    assert (tmp_path / "default" / "config.toml").read_text().endswith('compile_effort = "balanced"\n')


def test_cli_refuses_a_level_the_process_cannot_take(tmp_path, capsys):
    """This process compiles at the suite's level (XLA_FLAGS, conftest): another one asked for is refused before
    anything runs, a run without the flag takes and records the process's."""
    other = "full" if xla_flags.effort() != "full" else "fast"
    assert main([*TINY_DIP_LQR, "--out", str(tmp_path / "x"), "--compile-effort", other]) == 2
    assert "--compile-effort" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
