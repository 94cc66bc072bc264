"""``to_dataset``: a Monte Carlo result as one labelled per-seed dataset (xarray), for a user's own loop.

``jd.to_dataset(sol, plant, dt=loop.dt)`` takes what ``jd.monte_carlo`` returns and labels every per-seed number:
the result code and failure time of each seed, its final state, every metric (named by its path, as
``jd.summary`` names it) and, when the rollout saved them, the trajectories. ``solution_variables`` gives the same
variables as plain arrays, without xarray, for code that adds its own before building the dataset
(``jaxdip.dataset.build``). Needs the optional extra ``data`` for the dataset itself (``jaxdip.dataset``).
"""

from __future__ import annotations

from typing import Any, Mapping, Optional, Sequence

import jax
import numpy as np

from jaxdip import dataset
from jaxdip.engine import checks
from jaxdip.engine.simulate import RESULTS
from jaxdip.engine.summary import _path, _state_names

from jaxdip._public import public_dir

__all__ = ["solution_variables", "to_dataset"]
__dir__ = public_dir(globals())

RESULT_ATTRS = {"long_name": "per-seed result code (jaxdip.RESULTS)", "units": "1",
                "flag_values": [int(c) for c in RESULTS], "flag_meanings": " ".join(c.name for c in RESULTS)}


def _dims(path: str, shape: tuple, lead: tuple[str, ...], names, extra: Mapping[str, Sequence[str]]) -> tuple:
    rest = shape[len(lead):]
    for name in (path, path.split(".")[0]):  # the metric itself, or its top-level key (``u`` for ``u.var``)
        if name in extra and len(extra[name]) == len(rest):
            return (*lead, *extra[name])
    dims = [f"{path.split('.')[0]}_dim{i}" for i in range(len(rest))]
    if names is not None and rest and rest[-1] == len(names):
        dims[-1] = "state"  # one entry per state: labelled by the state names
    return (*lead, *dims)


def solution_variables(sol: Any, names: Any = None, *, dt: Optional[float] = None, save_dt: Optional[float] = None,
                       trajectories: bool = True, dims: Optional[Mapping[str, Sequence[str]]] = None,
                       units: Optional[Mapping[str, str]] = None) -> dict:
    """The per-seed variables of a ``jd.monte_carlo`` Solution: name -> (dims, values, attrs).

    ``result`` (the ``RESULTS`` code), ``ok`` (no failure), ``failed_at`` (period index of the first bad state,
    -1 while ok) and with ``dt`` ``failed_at_s`` (NaN for seeds that did not fail), ``final_x`` (the last good
    state) and every metric by its path (``x.mean``). A metric axis with one entry per state is the ``state``
    dimension; ``dims`` names the other axes (a path, or a metric's top-level key, -> names after the seed
    axis). With ``trajectories`` and a
    rollout that saved samples, each saved leaf (``saved`` or ``saved.<path>``) on (seed, time, ...); ``save_dt``:
    the time between saved samples in s (else ``time`` counts samples). ``units``: path -> units. A sweep's
    leading axis is the ``sweep`` dimension.
    """
    for field in ("final", "metrics", "result"):
        if not hasattr(sol, field):
            raise checks.ArgumentTypeError(f"to_dataset: sol must be what jd.monte_carlo returns (a Solution), "
                                           f"got {type(sol).__name__}")
    names = _state_names(names)
    units = dict(units or {})
    extra = dict(dims or {})
    code = np.asarray(sol.result)
    if code.ndim not in (1, 2):
        checks.fail("to_dataset", f"sol.result must be per seed (a Monte Carlo result), got shape {code.shape}")
    lead = ("seed",) if code.ndim == 1 else ("sweep", "seed")
    out = {"result": (lead, code.astype(np.int32), RESULT_ATTRS),
           "ok": (lead, code == RESULTS.ok, {"long_name": "the seed ended ok (result == 0)", "units": "1"})}
    at = np.asarray(sol.final.failed_at)
    out["failed_at"] = (lead, at, {"long_name": "period index of the first bad state (-1: did not fail)",
                                   "units": "1"})
    if dt is not None:
        out["failed_at_s"] = (lead, np.where(at >= 0, at * float(dt), np.nan),
                              {"long_name": "time of the first bad state (NaN: did not fail)", "units": "s"})
    x = np.asarray(sol.final.x)
    out["final_x"] = (_dims("final_x", x.shape, lead, names, extra), x,
                      {"long_name": "final plant state (the last good one for a failed seed)",
                       "units": units.get("final_x", "state units")})
    for keys, leaf in jax.tree_util.tree_flatten_with_path(sol.metrics)[0]:
        path, arr = _path(keys), np.asarray(leaf)
        out[path] = (_dims(path, arr.shape, lead, names, extra), arr,
                     {"long_name": f"per-seed metric {path}", "units": units.get(path, "")})
    if trajectories and sol.saved is not None:
        for keys, leaf in jax.tree_util.tree_flatten_with_path(sol.saved)[0]:
            path = "saved" + (f".{_path(keys)}" if keys else "")
            arr = np.asarray(leaf)
            tail = _dims(path, arr.shape, (*lead, "time"), names, extra)
            out[path] = (tail, arr, {"long_name": f"saved samples {path}", "units": units.get(path, "")})
    return out


def to_dataset(sol: Any, names: Any = None, *, dt: Optional[float] = None, save_dt: Optional[float] = None,
               key: Any = None, trajectories: bool = True, dims: Optional[Mapping[str, Sequence[str]]] = None,
               units: Optional[Mapping[str, str]] = None, attrs: Optional[Mapping] = None):
    """A ``jd.monte_carlo`` Solution as an ``xarray.Dataset`` with named dimensions (``seed``, ``state``,
    ``time``, ...): the variables of ``solution_variables`` (same arguments). ``names``: a plant or its state
    names, for the ``state`` coordinate; ``key``: the base key or int seed of the run, recorded as the attribute
    ``seeds_key``; ``attrs``: more global attributes. ``MissingExtra`` (naming ``pip install -e '.[data]'``)
    without xarray and h5netcdf. Write it with ``jaxdip.dataset.write(ds, "per_seed.nc")``."""
    variables = solution_variables(sol, names, dt=dt, save_dt=save_dt, trajectories=trajectories, dims=dims,
                                   units=units)
    coords = {}
    state_names = _state_names(names)
    if state_names is not None:
        coords["state"] = list(state_names)
    steps = [np.shape(v)[d.index("time")] for d, v, _ in variables.values() if "time" in d]
    if steps and save_dt is not None:
        coords["time"] = np.arange(steps[0]) * float(save_dt)
    head = dict(attrs or {})
    if key is not None:
        head["seeds_key"] = f"PRNGKey({key})" if isinstance(key, (int, np.integer)) else \
            np.asarray(jax.random.key_data(key)).tolist()
    ds = dataset.build(variables, coords, head)
    if "time" in ds.coords:
        ds["time"].attrs["units"] = "s"
    return ds
