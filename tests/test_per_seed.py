"""Per-seed datasets (docs/data.md): for every experiment that keeps them, the statistics of ``results`` recomputed
with xarray/NumPy from its per_seed.nc equal metrics.json's to 1e-12; the dataset of a user's loop
(``jd.to_dataset``) holds the Solution's numbers; the provenance of metrics.json, the PNGs and report.md agree with
git, hashlib and the folder's config.toml; the documentation's example runs; without the extra, a one-line error."""

from __future__ import annotations

import hashlib
import itertools
import json
import pathlib
import re
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd
from jaxdip import cli, xla_flags
from jaxdip import config as C
from jaxdip.runner import get, registry, run_experiment
from jaxdip.runner.results import NA
from jaxdip.stats import mean_ci, wilson

xr = pytest.importorskip("xarray")
pytest.importorskip("h5netcdf")

ROOT = pathlib.Path(__file__).resolve().parents[1]

# each experiment at the smallest scale that still has seeds to summarise (quick overrides, then these)
TINY = {
    "dip-lqr": ["seeds=6", "duration=0.2", "record_every=1"],
    "dip-controllers": ["seeds=4", "duration=0.1"],
    "dip-cpx-ldf": ["seeds=4", "duration=0.1", "sweep_seeds=3", "sweep_points=2", "velocity_trial=false"],
    "lorenz-mhe": ["seeds=4", "duration=0.3", "chunk_steps=100", "record_every=5"],
    "rwp-remark3": ["seeds=4", "duration=1.0", "tail=0.5", "wheel_biases=[0.5, 1.0]"],
    "twip-extra-control": ["seeds=4", "chunk_seeds=4", "duration=1.0"],
    "ifn-protection": ["seeds=512", "quad_panels=256", "bisect_panels=256", "lattice_panels=128", "lineages=64",
                       "generations=3", "tune_steps=5", "tune_batch=256"],
    "tune": ["steps=2", "heldout_seeds=4", "landscape_points=3"],
    "twip-dmso": ["seeds=4", "det_seeds=2", "duration=1.0", "duration_fine=0.5", "tail_s=0.5", "chunk_seeds=4"],
    "eki-dip": ["seeds=4", "ensemble=6", "iterations=2", "chunk=2", "T=0.3", "t_star=0.1", "grad_steps=0",
                "eval_states=2", "judge_duration=0.3", "early_stop=false", "min_success=2"],
}


def _run(tmp_path, exp_id: str, what: str = "final") -> pathlib.Path:
    exp = get(exp_id)
    cfg = C.load(exp.config_cls, quick=exp.quick, sets=TINY.get(exp_id, []))
    out = tmp_path / exp_id
    run_experiment(exp, cfg, str(out), compile_effort=xla_flags.effort(), per_seed=what)
    return out


def _keys(template: str, where: dict) -> list[str]:
    """A ``summarised_as`` template's keys: split at its dots first, so a label may hold dots of its own."""
    return [part.format(**where) for part in template.split(".")]


def _at(results: dict, path: list[str]):
    v = results
    for part in path:
        v = v[int(part)] if isinstance(v, list) else v[part]
    return v


def _expanded(ds, name: str):
    """(results path, interval path or None, per-seed values, the mask's values) for every label combination of
    the variable's dimensions other than its seeds (the first) that its ``summarised_as`` names; the others must
    have one entry."""
    var = ds[name]
    template = var.attrs["summarised_as"]
    named = re.findall(r"\{(\w+)\}", template)
    others = [d for d in var.dims[1:] if d not in named]
    assert all(var.sizes[d] == 1 for d in others), (name, template, others)
    var = var.isel({d: 0 for d in others})
    mask = ds[var.attrs["over"]] if "over" in var.attrs else None
    for labels in itertools.product(*(ds[d].values.tolist() for d in named)):
        where = dict(zip(named, labels))
        v = var.sel(where)
        m = None if mask is None else mask.sel({k: w for k, w in where.items() if k in mask.dims})
        interval = var.attrs.get("interval_as")
        yield (_keys(template, where), interval and _keys(interval, where), v.values,
               None if m is None else m.values.astype(bool))


def _close(got, want, path):
    assert got == pytest.approx(want, abs=1e-12, rel=1e-12), path


def check_against_metrics(folder: pathlib.Path) -> int:
    """Every statistic the dataset names, recomputed from the file, against metrics.json; the number checked."""
    results = json.loads((folder / "metrics.json").read_text())["results"]
    ds = xr.open_dataset(folder / "per_seed.nc", engine="h5netcdf").load()
    checked = 0
    for name in ds.data_vars:
        if "summarised_as" not in ds[name].attrs:
            continue
        statistic = ds[name].attrs["statistic"]
        for path, interval, values, mask in _expanded(ds, name):
            if statistic == "fraction_wilson":
                frac, ci = wilson(int(values.astype(bool).sum()), values.size)
            else:
                assert statistic == "mean_ci95", (name, statistic)
                keep = values[mask] if mask is not None else values
                keep = keep[np.isfinite(keep)]
                if keep.size == 0:  # a statistic over no seed is left out of results, or "n/a" in a list
                    try:
                        assert _at(results, path) == NA, path
                    except (KeyError, IndexError):
                        pass
                    continue
                frac, ci = float(np.mean(keep)), mean_ci(values, mask)[1]
            _close(_at(results, path), frac, path)
            if interval:
                _close(_at(results, interval), ci, interval)
            checked += 1
    return checked


# run in the default suite (each a few seconds); the others, whose tiny runs still compile several loops, with -m slow
FAST = ("dip-lqr", "rwp-remark3")
KEEPING = [pytest.param(i, marks=() if i in FAST else pytest.mark.slow)
           for i, e in sorted(registry().items()) if e.per_seed]


@pytest.mark.parametrize("exp_id", KEEPING)
def test_per_seed_statistics_equal_metrics(tmp_path, exp_id):
    out = _run(tmp_path, exp_id)
    assert check_against_metrics(out) > 0
    ds = xr.open_dataset(out / "per_seed.nc", engine="h5netcdf")
    assert ds.attrs["experiment"] == exp_id and "time" not in ds.dims  # trajectories only when asked
    assert ds.attrs["config_toml"] == (out / "config.toml").read_text()
    for name in ds.data_vars:
        assert ds[name].dims[0].endswith("seed") and ds[name].attrs.get("units") is not None, name
        if name.split(".")[-1] == "result":
            assert set(np.unique(ds[name].values)) <= {0, 1, 2}


def test_trajectories_provenance_and_the_documented_example(tmp_path):
    out = _run(tmp_path, "dip-lqr", "trajectories")
    ds = xr.open_dataset(out / "per_seed.nc", engine="h5netcdf")
    assert ds["saved"].dims == ("seed", "time", "angle") and ds.sizes["seed"] == 6
    assert np.allclose(np.diff(ds["time"].values), 0.001)
    # the final state's alpha is the last saved alpha of every seed that did not fail (saved each period)
    ok = ds["ok"].values
    assert ok.all()
    metrics = json.loads((out / "metrics.json").read_text())
    prov = metrics["provenance"]
    assert prov["config_sha256"] == hashlib.sha256((out / "config.toml").read_bytes()).hexdigest()
    assert prov["packages"]["numpy"] == np.__version__ and prov["jaxdip_version"] == jd.__version__
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode == 0:
        assert prov["git_commit"] == head.stdout.strip()
    from PIL import Image

    text = Image.open(out / "band_alpha_theta.png").text
    assert json.loads(text["jaxdip:packages"]) == prov["packages"] and text["jaxdip:command"] == prov["command"]
    assert ds.attrs["config_sha256"] == prov["config_sha256"]
    assert (out / "report.md").read_text().rstrip().splitlines()[-1].endswith(f"`{prov['regenerate']}`")
    # docs/data.md's example, as written there
    code = re.search(r"```python\n(.*?)```", (ROOT / "docs" / "data.md").read_text(), re.S).group(1)
    run = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert (out / "hist_mean_abs_alpha.png").stat().st_size > 1000
    mean_abs = float(re.search(r"mean \|alpha\| (\S+) rad", run.stdout).group(1))
    assert mean_abs == pytest.approx(metrics["results"]["states"]["alpha"]["mean_abs"], rel=1e-3)


def test_to_dataset_labels_a_users_monte_carlo():
    plant, dt = jd.plants.DIP(), 0.001
    A, B = jd.linearize(plant)
    K, _, _ = jd.control.lqr(A, B, jnp.diag(jnp.array([30.0, 350, 100, 0, 0, 0])), 0.1)
    loop = jd.Loop(plant, sensor=jd.sensors.WhiteNoise(jnp.full(6, 1e-3)), estimator=jd.Passthrough(),
                   controller=jd.control.StateFeedback(K), dt=dt, state_bound=1.0)
    rollout = jd.Rollout(loop, x0=jd.Ball(jnp.zeros(6), 0.1), steps=300, metrics={"x": jd.metrics.Moments("x")},
                         save=lambda s: s.x[1], save_every=30)
    sol = jd.monte_carlo(rollout, 3, 24)
    ds = jd.to_dataset(sol, plant, dt=dt, save_dt=30 * dt, key=3)
    codes = np.asarray(sol.result)
    assert 0 < (codes != 0).sum() < 24  # failed and live seeds both
    np.testing.assert_array_equal(ds["result"].values, codes)
    np.testing.assert_array_equal(ds["final_x"].sel(state="theta").values, np.asarray(sol.final.x)[:, 2])
    at = np.asarray(sol.final.failed_at)
    np.testing.assert_array_equal(np.isnan(ds["failed_at_s"].values), at < 0)
    np.testing.assert_allclose(ds["failed_at_s"].values[at >= 0], at[at >= 0] * dt)
    assert ds["saved"].dims == ("seed", "time") and ds.sizes["time"] == 10 and ds.attrs["seeds_key"] == "PRNGKey(3)"
    s = jd.summary(sol, plant)
    live = ds["x.mean_abs"].where(ds["ok"], drop=True).mean("seed")
    np.testing.assert_allclose(live.values, s["x.mean_abs"].mean, rtol=1e-12)


def test_without_the_extra_per_seed_is_one_line_naming_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "xarray", None)  # import xarray now raises ImportError
    assert cli.main(["run", "dip-lqr", "--quick", "--per-seed", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install -e '.[data]'" in err and err.startswith("error: --per-seed")
    assert not (tmp_path / "o").exists()
