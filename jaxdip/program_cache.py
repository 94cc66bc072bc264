"""Traced programs kept on disk (``jax.export``), so a warm run skips tracing and lowering, not only compilation.

XLA's persistent cache keys a compiled program by its lowered module, so every run still traces the Python
code and lowers it before that cache can answer: in a warm ``--quick`` run that was most of the time left
(docs/performance.md, warm start). This cache sits one step earlier: it keys a call by everything its trace can
depend on, known without tracing (``jaxdip.program_key``), and on a hit calls the stored program (StableHLO,
serialised by ``jax.export``) as it is; the compiled code then comes from XLA's cache as before.

A call the key cannot pin down goes the ordinary way (``MISS``): ``Unkeyable`` arguments, a program that does not
export (a host callback), a program partitioned over more devices than its inputs are on (its entry says so, so
the next process does not trace it to find out), an entry that cannot be read (it is exported again over it).
Inputs sharded over this process's devices are served, with their shardings in the key. Results are the same
either way: the stored program is the one JAX would have compiled (tests/test_program_cache.py compares them bit
for bit, and ``jaxdip reproduce --quick`` gives the same results with and without it).

Off unless ``enable`` is called: the CLI turns it on with the compilation cache, in a ``programs`` folder inside
it (``--no-compile-cache`` turns both off). The experiments' entries are 60-130 kB; nothing removes old ones
(as with XLA's cache, deleting the folder is safe).
"""

from __future__ import annotations

import functools
import os
import pickle
from typing import Any, Callable

from jaxdip.outdir.files import write_file_atomic
from jaxdip.program_key import Unkeyable, fingerprint, function_key, is_input

__all__ = ["MISS", "call", "counts", "enable", "enabled_folder", "jit"]

MISS = object()  # what ``call`` returns when the call must go the ordinary way

_FOLDER: list[str | None] = [None]
_MEMO: dict[bytes, Any] = {}  # key -> _Program, or None: not exportable
# how this process's calls went: programs read from disk, exported and written, and calls that went the ordinary
# way (not keyable, not exportable); ``python -m jaxdip.bench.warm`` reports them
_COUNTS = {"read": 0, "exported": 0, "ordinary": 0}


def enable(folder: str | None) -> None:
    """Keep exported programs in ``folder`` (created on first write); ``None`` turns the cache off."""
    _FOLDER[0] = folder
    _MEMO.clear()


def enabled_folder() -> str | None:
    """The folder in use, or None when the cache is off."""
    return _FOLDER[0]


def counts() -> dict[str, int]:
    """This process's programs read from disk and exported, and its calls that went the ordinary way while the
    cache was on."""
    return dict(_COUNTS)


class _Program:
    """An exported program and its output tree; called through one ``jax.jit`` per device its inputs are on.

    The device is given to ``jit`` explicitly: an exported program's outputs are committed to their device, so
    the second call of a loop (tune's steps: the gradient, the update, the gradient again) would otherwise see
    committed inputs where the first saw uncommitted ones, and compile the same program again."""

    def __init__(self, exported, out_tree, name: str):
        self.exported, self.out_tree, self.name = exported, out_tree, name
        self.by_device: dict = {}

    def __call__(self, leaves: list):
        import jax

        devices = {d for leaf in leaves if hasattr(leaf, "devices") for d in leaf.devices()}
        if self.exported.nr_devices > 1:  # a partitioned program: its inputs carry their shardings (the key's)
            if len(devices) != self.exported.nr_devices:
                raise Unkeyable("inputs on other devices than the program's")
            place = frozenset(devices)
            run = self.by_device.get(place)
            if run is None:
                run = self.by_device[place] = jax.jit(self._program())
            return jax.tree_util.tree_unflatten(self.out_tree, run(*leaves))
        device = devices.pop() if len(devices) == 1 else jax.devices()[0]
        if devices:  # inputs on several devices (each on one): not a case the cache serves
            raise Unkeyable("inputs on different devices")
        run = self.by_device.get(device)
        if run is None:
            run = self.by_device[device] = jax.jit(self._program(),
                                                   in_shardings=jax.sharding.SingleDeviceSharding(device))
        return jax.tree_util.tree_unflatten(self.out_tree, run(*leaves))

    def _program(self) -> Callable:
        exported = self.exported

        def program(*xs):
            return exported.call(*xs)

        program.__name__ = program.__qualname__ = self.name  # compile events name it as the direct call
        return program


def _spread(leaf):
    """The sharding of an input laid out over several devices (exported with it: it shapes the partitioned
    program and is part of the key), else None."""
    import jax

    if isinstance(leaf, jax.Array) and len(leaf.devices()) > 1:
        return leaf.sharding
    return None


def _export(fun: Callable, packed: tuple, name: str):
    import jax

    leaves, in_tree = jax.tree_util.tree_flatten(packed)
    where = [i for i, leaf in enumerate(leaves) if is_input(leaf)]
    box = {}

    def flat(*dynamic):
        full = list(leaves)
        for i, v in zip(where, dynamic):
            full[i] = v
        args, kwargs = jax.tree_util.tree_unflatten(in_tree, full)
        out = fun(*args, **kwargs)
        out_leaves, box["tree"] = jax.tree_util.tree_flatten(out)
        return out_leaves

    # not ``name``: JAX logs "Compiling <name>" when it lowers, and the wrapper that runs the program is lowered
    # under ``name`` (one such line per program, as for a direct call)
    flat.__name__ = flat.__qualname__ = f"{name}_export"
    avals = [jax.ShapeDtypeStruct(leaves[i].shape, leaves[i].dtype, weak_type=getattr(leaves[i], "weak_type", False),
                                  sharding=_spread(leaves[i]))
             for i in where]
    exported = jax.export.export(jax.jit(flat))(*avals)
    if exported.nr_devices > 1 and not any(a.sharding is not None for a in avals):
        # partitioned inside (a Monte Carlo that shards its own batches) on inputs of one device: a stored
        # program cannot be called so (JAX asks its inputs to be on as many devices as it was exported for)
        raise Unkeyable("partitioned over devices its inputs are not on")
    tree_hex = pickle.dumps(box["tree"]).hex().encode()
    return tree_hex + b"\n" + exported.serialize()


def call(fun: Callable, args: tuple, name: str | None = None, kwargs: dict | None = None,
         fun_key: tuple[bytes, frozenset] | None = None):
    """``fun(*args)`` through a stored program, or ``MISS`` when the cache is off or the call cannot go through
    it (the caller then calls ``fun`` the ordinary way). ``fun`` must be pure, its inputs the array leaves of
    ``args`` (as under ``jax.jit``). ``name``: what compile events call the program (``fun``'s name)."""
    name = name or getattr(fun, "__name__", "program")
    folder = _FOLDER[0]
    if folder is None:
        return MISS
    import jax

    packed = (tuple(args), dict(kwargs or {}))
    try:
        key = fingerprint(fun, packed, fun_key)
    except Unkeyable:
        _COUNTS["ordinary"] += 1
        return MISS
    if key not in _MEMO:
        _MEMO[key] = _entry(fun, packed, name, os.path.join(folder, key.hex()[:40] + ".jaxexport"))
    entry = _MEMO[key]
    try:
        if entry is not None:
            return entry([leaf for leaf in jax.tree_util.tree_leaves(packed) if is_input(leaf)])
    except Unkeyable:
        pass
    _COUNTS["ordinary"] += 1
    return MISS


# what an entry holds for a program the cache refused by design (``_export``'s Unkeyable), so the next process
# goes the ordinary way without tracing it a second time to find that out
_ORDINARY = b"ordinary\n"


def _entry(fun: Callable, packed: tuple, name: str, path: str):
    """The program stored at ``path``, or exported now (and written there); None when it does not export."""
    if os.path.exists(path):
        try:
            with open(path, "rb") as fh:
                blob = fh.read()
            if blob == _ORDINARY:
                return None
            entry = _load_blob(blob, name)
            _COUNTS["read"] += 1
            return entry
        except Exception:  # a damaged or foreign file: export again over it
            pass
    try:
        blob = _export(fun, packed, name)
    except Unkeyable:
        _write(path, _ORDINARY)
        return None
    except Exception:  # e.g. a host callback, which does not export: the ordinary call reports real errors
        return None
    _write(path, blob)
    _COUNTS["exported"] += 1
    return _load_blob(blob, name)


def _write(path: str, blob: bytes) -> None:
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        write_file_atomic(path, blob)
    except OSError:
        pass  # a read-only cache still serves this process from memory


def jit(fun: Callable, name: str | None = None) -> Callable:
    """``equinox.filter_jit(fun)`` (array leaves traced, everything else static), through a stored program
    when the cache is on and the call can be keyed (``call``). ``fun``'s closure is part of the key, by value,
    taken at the first call: as under ``jax.jit``, what changes between calls must be an argument."""
    import equinox as eqx

    direct = eqx.filter_jit(fun)
    name = name or getattr(fun, "__name__", "program")
    known: list = []  # [function_key(fun)], or [None]: fun cannot be keyed

    @functools.wraps(fun)
    def run(*args, **kwargs):
        if _FOLDER[0] is not None:
            if not known:
                try:
                    known.append(function_key(fun))
                except Unkeyable:
                    known.append(None)
            if known[0] is None:
                _COUNTS["ordinary"] += 1
            else:
                out = call(fun, args, name, kwargs, known[0])
                if out is not MISS:
                    return out
        return direct(*args, **kwargs)

    return run


class _TreeUnpickler(pickle.Unpickler):
    """Reads a stored output tree, naming nothing but the tree type, its registry and container classes: a
    pickle may call whatever it names, so a file planted in the cache folder must not reach a function
    (os.system, a file remover). Only modules of the project, JAX, equinox and the builtins are imported to look
    a name up."""

    def find_class(self, module: str, name: str):
        import equinox as eqx
        import jax

        if module.split(".")[0] in ("jax", "jaxlib", "jaxdip", "experiments", "equinox", "builtins", "collections"):
            obj = super().find_class(module, name)
            if obj is jax.tree_util.PyTreeDef or obj is jax.tree_util.default_registry:
                return obj
            if isinstance(obj, type) and (obj in (tuple, list, dict, type(None)) or issubclass(obj, eqx.Module)
                                          or (issubclass(obj, tuple) and hasattr(obj, "_fields"))):
                return obj
        raise pickle.UnpicklingError(f"{module}.{name} may not appear in a stored program's output tree")


def _load_blob(blob: bytes, name: str):
    import io

    import jax

    tree_hex, program = blob.split(b"\n", 1)
    out_tree = _TreeUnpickler(io.BytesIO(bytes.fromhex(tree_hex.decode()))).load()
    if not isinstance(out_tree, jax.tree_util.PyTreeDef):
        raise pickle.UnpicklingError("a stored program's output tree is not a tree structure")
    return _Program(jax.export.deserialize(bytearray(program)), out_tree, name)
