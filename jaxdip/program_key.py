"""The key of a traced program (``jaxdip.program_cache``): everything a JAX trace can depend on, known without
tracing it.

- the code: every ``.py`` file of the ``jaxdip`` package and of the ``experiments`` package beside it, and the
  versions of the installed packages involved (jax, jaxlib, equinox, numpy, and any other whose functions,
  classes or modules the arguments hold);
- the arguments' tree structure, with each node's static data, and each array leaf's shape, dtype and weak type;
- every other leaf by value, deeply: numbers, strings, arrays held as constants (their bytes), functions (their
  module, name, bytecode, constants, defaults and closure contents), classes, modules, partials, bound methods,
  dataclass instances and the project's plain objects (their attributes);
- JAX's configuration (every option's value) and the backend's devices.

What it cannot pin down raises ``Unkeyable``: an object of a class from outside the project that carries state,
a function or class from a module outside the project, the standard library and the installed packages (a user's
script: its helpers in other files would not be in the key), a tracer, an array over several processes or
laid out other than by a ``NamedSharding``. An array over several devices of this process counts with its
sharding (the program's partitioning depends on it), by value.

Nothing here depends on the process: Python's string hashing (which orders the frozenset constants of
bytecode) is kept out, so a key computed in one process is found by the next.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import os
import sys
import types
from typing import Any, Callable

__all__ = ["Unkeyable", "fingerprint", "function_key", "is_input", "sharding_value"]

_ALWAYS = ("jax", "jaxlib", "equinox", "numpy")


class Unkeyable(Exception):
    """An argument the cache cannot fingerprint: the call goes the ordinary way."""


@functools.lru_cache(maxsize=None)
def _tree_hash(root: str) -> str:
    h = hashlib.sha256()
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(files):
            if name.endswith(".py"):
                path = os.path.join(folder, name)
                h.update(os.path.relpath(path, root).encode() + b"\0")
                with open(path, "rb") as fh:
                    h.update(fh.read() + b"\0")
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def _project_trees() -> tuple[str, ...]:
    here = os.path.dirname(os.path.abspath(__file__))
    trees = [here]
    beside = os.path.join(os.path.dirname(here), "experiments")
    if os.path.isfile(os.path.join(beside, "__init__.py")):
        trees.append(beside)
    return tuple(trees)


_STDLIB = frozenset(sys.stdlib_module_names) | {"builtins"}


@functools.lru_cache(maxsize=None)
def _module_key(modname: str) -> str:
    """What pins a module's code: the project's trees (hashed whole), the standard library (the Python version)
    or an installed distribution (its version). Anything else is refused."""
    top = (modname or "").split(".")[0]
    if top in ("jaxdip", "experiments"):
        return top
    if top in _STDLIB:
        return f"python {sys.version}"
    mod = sys.modules.get(top)
    path = getattr(mod, "__file__", None) or ""
    if "site-packages" in path or "dist-packages" in path:
        try:
            return f"{top}=={importlib.metadata.version(top)}"
        except importlib.metadata.PackageNotFoundError:
            dist = importlib.metadata.packages_distributions().get(top)
            if dist:
                return f"{top}=={importlib.metadata.version(dist[0])}"
    raise Unkeyable(f"module {modname!r} is not in the project, the standard library or an installed package")


class _Key:
    def __init__(self) -> None:
        self.h = hashlib.sha256()
        self.modules: set[str] = set()
        self.stack: set[int] = set()

    def put(self, *parts: object) -> None:
        for p in parts:
            self.h.update(repr(p).encode() + b"\x1f")

    def module(self, modname: str) -> None:
        self.modules.add(_module_key(modname))
        self.put("mod", modname)


def _array_bytes(x) -> tuple[str, tuple, bytes]:
    import jax
    import numpy as np

    if isinstance(x, jax.core.Tracer):
        raise Unkeyable("a tracer")
    if isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
        return str(x.dtype), x.shape, np.asarray(jax.random.key_data(x)).tobytes()
    a = np.asarray(x)
    return str(a.dtype), a.shape, a.tobytes()


def _static(k: _Key, obj: Any, depth: int = 0) -> None:
    """Put ``obj`` into the key by value, deeply, or raise Unkeyable."""
    import jax
    import numpy as np

    if depth > 200:
        raise Unkeyable("too deep")
    if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes)):
        k.put(type(obj).__name__, obj)
        return
    if isinstance(obj, (np.ndarray, np.generic, jax.Array)):
        k.put("array", *_array_bytes(obj))
        return
    if isinstance(obj, np.dtype):
        k.put("dtype", str(obj))
        return
    if isinstance(obj, jax.sharding.Sharding):
        k.put("sharding", sharding_value(obj))
        return
    if id(obj) in k.stack:
        raise Unkeyable("a cycle")
    k.stack.add(id(obj))
    try:
        _static_compound(k, obj, depth + 1)
    finally:
        k.stack.discard(id(obj))


def _static_compound(k: _Key, obj: Any, depth: int) -> None:
    if isinstance(obj, (tuple, list)) and type(obj) in (tuple, list):
        k.put(type(obj).__name__, len(obj))
        for item in obj:
            _static(k, item, depth)
    elif type(obj) is dict:
        k.put("dict", len(obj))
        for key in sorted(obj, key=repr):
            _static(k, key, depth)
            _static(k, obj[key], depth)
    elif isinstance(obj, (frozenset, set)):
        k.put(type(obj).__name__, sorted(repr(v) for v in obj))  # sets of plain values only
        for v in obj:
            if not (v is None or isinstance(v, (bool, int, float, str, bytes))):
                raise Unkeyable("a set of non-plain values")
    elif isinstance(obj, types.ModuleType):
        k.module(obj.__name__)
    elif isinstance(obj, type):
        k.module(obj.__module__)
        k.put("type", obj.__qualname__)
    elif isinstance(obj, enum.Enum):
        _static(k, type(obj), depth)
        k.put("enum", obj.name)
    elif isinstance(obj, types.FunctionType):
        k.module(obj.__module__)
        k.put("function", obj.__qualname__)
        _code(k, obj.__code__)
        _static(k, obj.__defaults__, depth)
        _static(k, obj.__kwdefaults__, depth)
        k.put("closure", len(obj.__closure__ or ()))
        for cell in obj.__closure__ or ():
            try:
                value = cell.cell_contents
            except ValueError:  # an empty cell
                k.put("empty cell")
                continue
            _static(k, value, depth)
    elif isinstance(obj, (types.BuiltinFunctionType, types.BuiltinMethodType)) and isinstance(
            getattr(obj, "__self__", None), (types.ModuleType, type(None))):
        k.module(getattr(obj, "__module__", None) or "builtins")
        k.put("builtin", obj.__qualname__)
    elif isinstance(obj, functools.partial):
        k.put("partial")
        _static(k, obj.func, depth)
        _static(k, obj.args, depth)
        _static(k, obj.keywords, depth)
    elif isinstance(obj, types.MethodType):
        k.put("method")
        _static(k, obj.__func__, depth)
        _static(k, obj.__self__, depth)
    elif dataclasses.is_dataclass(obj):
        _static(k, type(obj), depth)
        for f in dataclasses.fields(obj):
            k.put("field", f.name)
            _static(k, getattr(obj, f.name, None), depth)
    elif isinstance(obj, tuple) and hasattr(obj, "_fields"):  # a NamedTuple
        _static(k, type(obj), depth)
        for item in obj:
            _static(k, item, depth)
    elif type(obj).__module__.split(".")[0] in ("jaxdip", "experiments"):
        # a plain object of the project's: its class's code (hashed with the tree) and its attributes
        _static(k, type(obj), depth)
        state = dict(getattr(obj, "__dict__", {}))
        for cls in type(obj).__mro__:
            for slot in getattr(cls, "__slots__", ()):
                if isinstance(slot, str) and hasattr(obj, slot):
                    state[slot] = getattr(obj, slot)
        _static(k, state, depth)
    elif _is_stateless(obj):  # a sentinel: its behaviour is its class's
        _static(k, type(obj), depth)
        k.put("instance")
    else:
        raise Unkeyable(f"an object of type {type(obj).__module__}.{type(obj).__qualname__}")


def _is_stateless(obj: Any) -> bool:
    t = type(obj)
    if getattr(t, "__slots__", ()) or t.__module__.split(".")[0] in ("jaxdip", "experiments"):
        return False
    try:
        return not vars(obj)
    except TypeError:
        return False


def _code(k: _Key, code: types.CodeType) -> None:
    # the bytecode, the names and the constants, nested functions' code too, and the first line (two lambdas
    # with one qualified name are told apart); not marshal, whose frozenset constants follow the string hashing,
    # which differs from process to process
    k.put("code", code.co_code, code.co_names, code.co_varnames, code.co_freevars, code.co_cellvars,
          code.co_argcount, code.co_kwonlyargcount, code.co_posonlyargcount, code.co_flags, code.co_firstlineno)
    for const in code.co_consts:
        _const(k, const)


def _const(k: _Key, const: object) -> None:
    if isinstance(const, types.CodeType):
        _code(k, const)
    elif isinstance(const, (tuple, frozenset)):
        items = sorted(const, key=repr) if isinstance(const, frozenset) else const
        k.put(type(const).__name__, len(items))
        for item in items:
            _const(k, item)
    else:
        k.put(type(const).__name__, const)


def _treedef(k: _Key, td, depth: int = 0) -> None:
    data = td.node_data()
    if data is None:
        k.put("leaf")
        return
    kind, aux = data
    _static(k, kind, depth)
    _static(k, aux, depth)
    kids = td.children()
    k.put("children", len(kids))
    for child in kids:
        _treedef(k, child, depth + 1)


def sharding_value(sharding) -> tuple:
    """A ``NamedSharding`` by value: its mesh's devices (ids, kind, arrangement), axis names, partition spec and
    memory kind. Other shardings raise Unkeyable."""
    import jax

    if not isinstance(sharding, jax.sharding.NamedSharding):
        raise Unkeyable(f"a {type(sharding).__name__}")
    mesh = sharding.mesh
    devices = [(d.id, d.platform, d.device_kind) for d in mesh.devices.flat]
    spec = tuple(tuple(p) if isinstance(p, (tuple, list)) else p for p in sharding.spec)
    return ("named", devices, tuple(mesh.devices.shape), tuple(mesh.axis_names), spec, sharding.memory_kind)


def is_input(leaf: Any) -> bool:
    """Whether a leaf is one of the program's inputs (an array), not part of its key by value."""
    import jax
    import numpy as np

    return isinstance(leaf, (jax.Array, np.ndarray))


def function_key(fun: Callable) -> tuple[bytes, frozenset]:
    """``fun`` by value (its code, defaults and closure, deeply) and the package versions it involves, or raise
    Unkeyable."""
    k = _Key()
    _static(k, fun)
    return k.h.digest(), frozenset(k.modules)


def fingerprint(fun: Callable, args: tuple, fun_key: tuple[bytes, frozenset] | None = None) -> bytes:
    """The key of ``fun(*args)``'s trace, or raise Unkeyable. Array leaves of ``args`` count by shape, dtype and
    weak type (they are the program's inputs); everything else by value. ``fun_key``: ``function_key(fun)``,
    if already known."""
    import jax

    k = _Key()
    k.put("jax config", sorted((name, repr(getattr(jax.config, name, None))) for name in jax.config.values))
    k.put("backend", jax.default_backend(), [d.device_kind for d in jax.local_devices()])
    digest, modules = fun_key or function_key(fun)
    k.h.update(digest)
    k.modules |= modules
    leaves, td = jax.tree_util.tree_flatten(args)
    _treedef(k, td)
    for leaf in leaves:
        if is_input(leaf):
            if isinstance(leaf, jax.core.Tracer):
                raise Unkeyable("a tracer")
            layout = None
            if isinstance(leaf, jax.Array) and len(leaf.devices()) != 1:
                if not leaf.is_fully_addressable:
                    raise Unkeyable("an array over several processes")
                layout = sharding_value(leaf.sharding)
            k.put("input", tuple(leaf.shape), str(leaf.dtype), bool(getattr(leaf, "weak_type", False)), layout)
        else:
            _static(k, leaf)
    for name in _ALWAYS:
        k.modules.add(_module_key(name))
    k.put("packages", sorted(k.modules))
    k.put("trees", [_tree_hash(t) for t in _project_trees()])
    return k.h.digest()
