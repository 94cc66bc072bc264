"""Per-seed datasets: labelled arrays (an ``xarray.Dataset``) written to one netCDF file through h5netcdf.

One file (``per_seed.nc`` in an experiment's folder) that any netCDF reader opens without jaxdip: named
dimensions (``seed``, ``state``, ``time``, ...), units and descriptions on every variable, and the run's
provenance (config, versions, commit, the seeds' key) as global attributes. The format's packages are the
optional extra ``data`` (``pip install -e '.[data]'``); they are imported only inside these functions, so the rest
of jaxdip never needs them. docs/data.md describes the layout.
"""

from __future__ import annotations

import json
import os
from typing import Any, Mapping

import numpy as np

from jaxdip._public import public_dir

__all__ = ["EXTRA", "MissingExtra", "available", "require", "build", "write", "read"]
__dir__ = public_dir(globals())

EXTRA = "pip install -e '.[data]'"

# a variable is (dims, values, attrs), as xarray's Dataset constructor takes it
Variable = tuple[tuple[str, ...], Any, dict]


class MissingExtra(ImportError):
    """Per-seed datasets were asked for without their packages (xarray, h5netcdf): the message names the extra."""


def available() -> bool:
    """Whether xarray and h5netcdf can be imported."""
    try:
        require()
    except MissingExtra:
        return False
    return True


def require():
    """The ``xarray`` module, or ``MissingExtra`` naming the extra that provides it and h5netcdf."""
    try:
        import h5netcdf  # noqa: F401  (the engine xarray writes with)
        import xarray
    except ImportError as e:
        raise MissingExtra(f"per-seed datasets need xarray and h5netcdf ({e.name} is missing): {EXTRA}") from None
    return xarray


def _attr(v):
    # netCDF attributes hold strings, numbers and flat arrays of numbers: everything else as JSON text
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (str, int, float, np.integer, np.floating)):
        return v
    if isinstance(v, (list, tuple)) and v and all(isinstance(e, (int, float)) and not isinstance(e, bool) for e in v):
        return np.asarray(v)
    return json.dumps(v, default=str)


def _attrs(attrs: Mapping | None) -> dict:
    return {str(k): _attr(v) for k, v in (attrs or {}).items() if v is not None}


def build(variables: Mapping[str, Variable], coords: Mapping[str, Any] | None = None,
          attrs: Mapping | None = None):
    """An ``xarray.Dataset`` of ``variables`` (name -> (dims, values, attrs)), with ``coords`` (dimension ->
    labels; ``seed`` defaults to 0 .. n-1, the index i of the key ``fold_in(base, i)``; or name -> (dimension,
    values) for a coordinate beside them, such as ``state_units``) and global ``attrs``.
    Booleans stay booleans (xarray stores them as int8 and reads them back as bool)."""
    xr = require()
    data = {}
    for name, (dims, values, vattrs) in variables.items():
        arr = np.asarray(values)
        if len(dims) != arr.ndim:
            raise ValueError(f"per-seed variable {name!r}: {arr.ndim} axes but dims {tuple(dims)}")
        data[name] = (tuple(dims), arr, _attrs(vattrs))
    ds = xr.Dataset(data, attrs=_attrs(attrs))
    labels = dict(coords or {})
    for dim in ds.dims:
        if str(dim).endswith("seed") and dim not in labels:  # seed, or the seeds of a part run with its own count
            labels[dim] = np.arange(ds.sizes[dim])
    for dim, values in labels.items():
        if isinstance(values, tuple) and len(values) == 2 and isinstance(values[0], str):
            # (dimension, values): a coordinate beside the labels, such as each state's units
            ds = ds.assign_coords({dim: (values[0], np.asarray(values[1]))})
        elif dim in ds.dims:
            values = np.asarray(values)
            ds = ds.assign_coords({dim: values.astype(str) if values.dtype.kind in "OU" else values})
    for dim in ds.dims:
        if str(dim).endswith("seed"):
            ds[dim].attrs["long_name"] = "Monte Carlo seed i: its key is fold_in(base key, i)"
    return ds


def write(ds, path: str) -> None:
    """Write ``ds`` to the netCDF file ``path`` (h5netcdf), through a temporary name renamed when complete."""
    require()
    tmp = f"{path}.tmp-{os.getpid()}"
    try:
        ds.to_netcdf(tmp, engine="h5netcdf")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def read(path: str):
    """Open a per-seed dataset (loaded into memory, the file closed)."""
    xr = require()
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return ds.load()
