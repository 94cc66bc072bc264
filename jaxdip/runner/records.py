"""One trajectory of a closed loop as a CSV table, and the table read back (NumPy only).

A record is a dict of columns, each ``(T,)`` or ``(T, k)``; in the file a ``(T, k)`` column ``y`` is the CSV
columns ``y[0] .. y[k-1]``. Numbers are written with 17 significant digits (``%.17g``), which round-trips every
float64 exactly, so an estimator run on the file (``jd.run_estimator``) sees the loop's numbers to the bit.

``loop_record(rollout, key)`` simulates one trial of a ``jd.Rollout`` (the trial a Monte Carlo run gives the
key ``fold_in(base, seed)``) and returns its record:

    t          k dt
    x          the true state at the start of period k
    y          the measurement at period k
    u          the controller's output u_k (the input an estimator is given at k + 1: ``run_estimator``'s us)
    u_applied  what the plant received in period k (the actuator's output)
    xhat       the estimate handed to the controller
    xhat.NAME  every member NAME of a ``jd.FanOut`` estimator
    key_init, key_est   the estimator's init key and its key at period k (raw uint32 words, exact as float64),
               so that an estimator that draws (``InitialError``) repeats its draws: ``estimator_keys(record)``
"""

from __future__ import annotations

import io
import os
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxdip.engine import checks
from jaxdip.engine.driver import Rollout
from jaxdip.engine.roles import FanOutAux
from jaxdip.engine.simulate import simulate

from jaxdip._public import public_dir

__all__ = ["write_csv", "read_csv", "loop_record", "estimator_keys"]
__dir__ = public_dir(globals())

_COLUMN = re.compile(r"^(.*)\[(\d+)\]$")


def write_csv(path: str, record: dict) -> None:
    """Write ``record`` (name -> (T,) or (T, k) array) to ``path``: a header line, then one line per sample."""
    names, blocks, T = [], [], None
    for name, value in record.items():
        if not isinstance(name, str) or not name or any(c in name for c in ',[]"\n'):
            raise checks.ArgumentError(f"write_csv: column names must be plain text without , [ ] or quotes, "
                                       f"got {name!r}")
        a = np.asarray(value, dtype=np.float64)
        if a.ndim not in (1, 2):
            raise checks.ArgumentError(f"write_csv: column {name!r} must be (T,) or (T, k), got shape {a.shape}")
        if T is None:
            T = a.shape[0]
        if a.shape[0] != T:
            raise checks.ArgumentError(f"write_csv: column {name!r} has {a.shape[0]} rows, the first has {T}")
        names += [name] if a.ndim == 1 else [f"{name}[{i}]" for i in range(a.shape[1])]
        blocks.append(a.reshape(T, -1))
    table = np.concatenate(blocks, axis=1) if blocks else np.zeros((0, 0))
    buf = io.StringIO()
    np.savetxt(buf, table, fmt="%.17g", delimiter=",", header=",".join(names), comments="")
    tmp = f"{path}.tmp-{os.getpid()}"
    with open(tmp, "w") as fh:
        fh.write(buf.getvalue())
    os.replace(tmp, path)


def read_csv(path: str) -> dict:
    """The record in ``path`` (from ``write_csv``): columns ``y[0] .. y[k-1]`` come back as one (T, k) array
    ``y``, a plain column as (T,); float64 throughout."""
    with open(path) as fh:
        header = fh.readline().strip()
        table = np.loadtxt(fh, delimiter=",", dtype=np.float64, ndmin=2)
    names = header.split(",")
    if table.size and table.shape[1] != len(names):
        raise checks.ArgumentError(f"read_csv: {path} has {len(names)} names in its header but "
                                   f"{table.shape[1]} values a row")
    groups: dict = {}
    for j, name in enumerate(names):
        m = _COLUMN.match(name)
        base, idx = (m.group(1), int(m.group(2))) if m else (name, None)
        groups.setdefault(base, []).append((idx, j))
    out = {}
    for base, cols in groups.items():
        if cols[0][0] is None:
            out[base] = table[:, cols[0][1]]
        else:
            out[base] = table[:, [j for _, j in sorted(cols)]]
    return out


def estimator_keys(record: dict):
    """``(init_key, step_keys)`` of a record's estimator, for ``run_estimator(..., keys=...)``."""
    init = np.asarray(record["key_init"][0], dtype=np.float64).astype(np.uint32)
    steps = np.asarray(record["key_est"], dtype=np.float64).astype(np.uint32)
    return jnp.asarray(init), jnp.asarray(steps)


def _save(sample) -> dict:
    rec = {"t": sample.t, "x": sample.x, "y": jnp.atleast_1d(sample.y), "u": sample.u,
           "u_applied": jnp.atleast_1d(sample.u_applied), "xhat": sample.xhat}
    aux = sample.aux.estimator
    if isinstance(aux, FanOutAux):
        rec.update({f"xhat.{name}": v for name, v in aux.xhat.items()})
    return rec


def loop_record(rollout: Rollout, key) -> dict:
    """The record of the trial of ``rollout`` with key ``key`` (all its ``steps`` periods), as NumPy arrays."""
    if not isinstance(rollout, Rollout):
        raise checks.ArgumentTypeError(f"loop_record: rollout must be a jaxdip Rollout, got {type(rollout).__name__}")

    @eqx.filter_jit
    def go(r, key):
        sol = simulate(r.loop, r.initial_state(key), key, r.steps, save=_save)
        base = r.loop.keys.base(key)
        init_key = r.loop.keys.init(key)[1]
        step_keys = jax.vmap(lambda k: r.loop.keys.period(base, k)[1])(jnp.arange(r.steps, dtype=jnp.int32))
        return sol.saved, init_key, step_keys

    saved, init_key, step_keys = go(rollout, key)
    rec = {name: np.asarray(v) for name, v in saved.items()}
    T = rec["t"].shape[0]
    rec["key_init"] = np.broadcast_to(np.asarray(_raw(init_key), np.float64), (T, 2))
    rec["key_est"] = np.asarray(_raw(step_keys), np.float64).reshape(T, -1)
    return rec


def _raw(key):
    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.key_data(key)
    return key
