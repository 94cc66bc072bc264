"""An ensemble's forward-model evaluations split by member over devices, and over processes with
``jax.distributed`` (``--distributed``).

Every device (of every process) holds the whole ensemble, evaluates its block of members (block ``i`` of
``J / devices`` consecutive members) and the blocks are gathered, so every device runs the (small) update on
the same numbers: one collective per iteration inside the compiled chunk, and the ensemble and its update are
identical on every process. Only the forward model is split, whatever the update rule: ``by_member`` wraps a
function from an ensemble block to its outputs, which every variant calls through ``EKI.evaluate``.

A member is evaluated by the same per-member program wherever it lands; the block sizes differ from one
layout to another, so results agree to rounding (about 1e-15 relative), not bit for bit.
"""

from __future__ import annotations

from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxdip import program_cache
from jaxdip.engine import checks

from jaxdip._public import public_dir

__all__ = ["AXIS", "member_devices", "by_member", "on_devices", "to_local"]
__dir__ = public_dir(globals())

AXIS = "members"  # the mesh axis the members are split over


def member_devices(J: int, shard: Optional[bool] = None) -> Optional[list]:
    """The devices an ensemble of ``J`` members is split over, or ``None`` for no split.

    Without ``jax.distributed``: this process's devices when ``shard`` is true, or when it is ``None`` and
    there are several that divide ``J``. With it: the devices of every process (unless ``shard=False``: then
    every process evaluates the whole ensemble itself), which must divide ``J``.
    """
    multi = jax.process_count() > 1
    devices = jax.devices() if multi else jax.local_devices()
    if shard is None:
        shard = multi or (len(devices) > 1 and J % len(devices) == 0)
    if not shard:
        return None
    if J % len(devices):
        where = f"{len(devices)} devices over {jax.process_count()} processes" if multi else f"{len(devices)} devices"
        raise checks.ArgumentError(f"splitting the ensemble by member: its size ({J}) must be a multiple of the "
                                   f"number of devices ({where})")
    return list(devices)


def by_member(forward: Callable, axis: Optional[str] = None) -> Callable:
    """``(V, key) -> Y`` from ``forward(V_block, key, first) -> Y_block`` (``first``: the index of the block's
    first member, for per-member keys). With ``axis`` (inside ``shard_map`` over that mesh axis) each device
    evaluates its block and the blocks are gathered, so every device returns the whole ``Y``."""

    def evaluate(V, key):
        if axis is None:
            return forward(V, key, jnp.zeros((), jnp.int32))
        n = jax.lax.psum(1, axis)
        size = V.shape[0] // n
        first = jax.lax.axis_index(axis) * size
        Y = forward(jax.lax.dynamic_slice_in_dim(V, first, size), key, first)
        return jax.lax.all_gather(Y, axis, tiled=True)

    return evaluate


def on_devices(fn: Callable, state, devices: Optional[list]):
    """``(jit(fn), state)`` ready to run: with ``devices``, ``fn(state, *rest)`` runs under ``shard_map`` over
    them (everything replicated in and out: ``fn`` splits the work itself with ``by_member``) and ``state`` is
    laid out as the calls return it (whole on every device), so the second call finds the program the first
    compiled. Every process must make the same calls in the same order."""
    if devices is None:
        return program_cache.jit(fn), state
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    whole = NamedSharding(Mesh(np.array(devices), (AXIS,)), PartitionSpec())
    if jax.process_count() > 1:
        # each process supplies its devices' copies of its (identical) value
        state = jax.tree_util.tree_map(
            lambda a: jax.make_array_from_callback(np.shape(a), whole, lambda i, a=np.asarray(a): a[i]), state)
    else:
        state = jax.device_put(state, whole)
    # through the program cache as on one device (the sharding is part of the key, by value); arrays over
    # several processes are not keyed and go the ordinary way
    def on_mesh(*args):
        return jax.shard_map(fn, mesh=whole.mesh, in_specs=PartitionSpec(), out_specs=PartitionSpec(),
                             check_vma=False)(*args)

    on_mesh.__name__ = getattr(fn, "__name__", "on_mesh")  # compile events name the program as fn
    return program_cache.jit(on_mesh), state


def to_local(tree):
    """Arrays whole on every device of several processes (``on_devices``' outputs) as plain arrays of this
    process (an exact copy of its first shard); other leaves as they are."""

    def local(a):
        if isinstance(a, jax.Array) and not a.is_fully_addressable:
            return jnp.asarray(np.asarray(a.addressable_data(0)))
        return a

    return jax.tree_util.tree_map(local, tree)
