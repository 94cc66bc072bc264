"""Batch a loop's carry in one pass: which carried values a ``vmap`` makes per-seed, found by reading the loop's
program instead of by re-batching it.

Under ``vmap`` JAX batches a ``lax.scan`` (or ``while_loop``) by a fixed point: it batches the whole loop body
with the carry that is batched on entry, sees which carried values come out batched, and starts again with
those, until nothing changes. A closed loop needs a round per link of its chain of dependencies (the noise makes
the measurement per-seed, then the estimate, then the control, then the plant state ...), and every round
re-batches each loop nested in the body, each with its own rounds: in a cached ``reproduce --quick`` these
rounds were about a third of all tracing.

The same fixed point can be read off the body's jaxpr: an equation's outputs are batched when one of its
inputs is, and loops, conditionals and calls inside it are read recursively by the same rules JAX's batchers
use. ``install`` wraps JAX's scan and while batching rules so that, inside ``active()`` (the library's own
compiled functions), the carried values the fixed point will batch are broadcast before JAX's rule runs: the
rule then settles in its first round, and builds exactly the program it would have built (the broadcast is the
one it would have inserted), so results are bit-identical. Whatever the reader does not know (collectives over
named axes, ``shard_map``, primitives with a program of their own it has no rule for) leaves the loop to JAX's
rule untouched. With ``JAXDIP_CHECK_CARRY_BATCHING=1`` every prediction is checked against JAX's own fixed
point (the tests do).
"""

from __future__ import annotations

import contextlib
import inspect
import os
import threading
from typing import Iterator, Sequence

_state = threading.local()
_installed = False

# primitives whose batching depends on a named axis (a reduction over the mapped axis is unbatched)
_NAMED = {"psum", "pmax", "pmin", "ppermute", "pbroadcast", "all_gather", "all_to_all", "axis_index",
          "psum_scatter", "reduce_scatter", "pgather", "psum_invariant", "pvary", "shard_map", "xla_pmap"}


@contextlib.contextmanager
def active() -> Iterator[None]:
    """Within this block (this thread), loops batched by ``vmap`` settle their carry in one round."""
    _state.depth = getattr(_state, "depth", 0) + 1
    try:
        yield
    finally:
        _state.depth -= 1


def _on() -> bool:
    return getattr(_state, "depth", 0) > 0


# ---- reading a jaxpr ------------------------------------------------------------------------------------------

def _jaxpr(j):
    return getattr(j, "jaxpr", j)  # ClosedJaxpr -> Jaxpr


def out_batched(jaxpr, in_batched: Sequence[bool]) -> list[bool] | None:
    """Which outputs of ``jaxpr`` (a Jaxpr or ClosedJaxpr) a vmap batches, given which inputs are batched; None
    when the program holds something this reader has no rule for."""
    from jax._src import core

    memo = getattr(_state, "memo", None)
    key = (id(jaxpr), tuple(bool(b) for b in in_batched))
    if memo is not None and key in memo:
        return memo[key][1]
    j = _jaxpr(jaxpr)
    bat: dict = {}
    for v, b in zip(j.invars, in_batched):
        bat[v] = bool(b)

    def get(v) -> bool:
        return False if isinstance(v, core.Literal) else bat.get(v, False)  # constvars: concrete, unbatched

    for eqn in j.eqns:
        ins = [get(v) for v in eqn.invars]
        outs = _eqn_out_batched(eqn, ins) if any(ins) else [False] * len(eqn.outvars)
        if outs is None:
            if memo is not None:
                memo[key] = (jaxpr, None)
            return None
        for v, b in zip(eqn.outvars, outs):
            bat[v] = b
    out = [get(v) for v in j.outvars]
    if memo is not None:
        memo[key] = (jaxpr, out)  # holding the jaxpr keeps its id from being reused while the memo lives
    return out


# primitives that call one program on their operands: batched exactly as that program is
_CALLS = {"jit": "jaxpr", "pjit": "jaxpr", "remat": "jaxpr", "checkpoint": "jaxpr", "closed_call": "call_jaxpr",
          "core_call": "call_jaxpr", "custom_jvp_call": "call_jaxpr", "custom_vjp_call": "call_jaxpr",
          "custom_vjp_call_jaxpr": "fun_jaxpr"}


def _has_program(params: dict) -> bool:
    from jax._src import core

    def prog(x):
        return isinstance(x, (core.Jaxpr, core.ClosedJaxpr))

    return any(prog(v) or (isinstance(v, (tuple, list)) and any(prog(u) for u in v)) for v in params.values())


def _eqn_out_batched(eqn, ins: list[bool]) -> list[bool] | None:
    name, p, n_out = eqn.primitive.name, eqn.params, len(eqn.outvars)
    if name in _NAMED or "axis_name" in p:
        return None
    if name == "scan":
        return _scan_out(p["jaxpr"], ins, p["num_consts"], p["num_carry"])[1]
    if name == "while":
        return _while_carry(p["cond_jaxpr"], p["body_jaxpr"], ins, p["cond_nconsts"], p["body_nconsts"])
    if name == "cond":
        if ins[0]:
            return [True] * n_out  # a per-seed branch index: JAX selects between all branches' outputs
        outs = [out_batched(br, ins[1:]) for br in p["branches"]]
        if any(o is None for o in outs):
            return None
        return [any(col) for col in zip(*outs)]
    if name == "custom_linear_solve":
        return _linear_solve_out(p["const_lengths"], p["jaxprs"], ins)
    if name == "optimization_barrier":
        return list(ins)
    if name in _CALLS and _CALLS[name] in p:
        return out_batched(p[_CALLS[name]], ins)
    if _has_program(p):
        return None
    return [True] * n_out  # a plain primitive: batched as soon as one operand is


def _scan_out(jaxpr, ins, num_consts: int, num_carry: int):
    """(carry batched on entry after the fixed point, all outputs batched) of a scan, or (None, None)."""
    consts, carry, xs = ins[:num_consts], list(ins[num_consts:num_consts + num_carry]), ins[num_consts + num_carry:]
    for _ in range(1 + num_carry):
        out = out_batched(jaxpr, consts + carry + xs)
        if out is None:
            return None, None
        new = [a or b for a, b in zip(carry, out[:num_carry])]
        if new == carry:
            return carry, carry + out[num_carry:]
        carry = new
    return None, None


def _linear_solve_out(const_lengths, jaxprs, ins):
    """JAX's fixed point between the batched parts of x and b of ``custom_linear_solve`` (jnp.linalg.solve)."""
    matvec, vecmat, solve, solve_t = jaxprs
    counts = list(const_lengths)
    cuts = [sum(counts[:i]) for i in range(5)]
    mv_b, vm_b, s_b, st_b = (ins[cuts[i]:cuts[i + 1]] for i in range(4))
    b0 = list(ins[cuts[4]:])
    n_op = len(matvec.out_avals)
    n_aux = len(solve.out_avals) - n_op
    b, x = b0, [False] * len(solve.out_avals)
    for _ in range(1 + len(b0) + len(x)):
        sx = out_batched(solve, s_b + b)
        if sx is None:
            return None
        x_out = [u or v for u, v in zip(sx, x)]
        if vecmat is not None:
            vx = out_batched(vecmat, vm_b + b)
            if vx is None:
                return None
            x_out = [u or v for u, v in zip([p or q for p, q in zip(vx, b)] + [True] * n_aux, x_out)]
        mb = out_batched(matvec, mv_b + x_out[:n_op])
        if mb is None:
            return None
        b_out = [u or v or w for u, v, w in zip(mb, b, b0)]
        if solve_t is not None:
            tb = out_batched(solve_t, st_b + x_out[:n_op])
            if tb is None:
                return None
            tb = [u or v for u, v in zip(tb, x_out)]
            b_out = [u or v for u, v in zip(b_out, tb[:len(b0)])]
        if x_out == x and b_out == b:
            return x
        x, b = x_out, b_out
    return None


def _while_carry(cond_jaxpr, body_jaxpr, ins, cond_nconsts: int, body_nconsts: int):
    cconsts, bconsts = ins[:cond_nconsts], ins[cond_nconsts:cond_nconsts + body_nconsts]
    carry = list(ins[cond_nconsts + body_nconsts:])
    for _ in range(1 + len(carry)):
        out = out_batched(body_jaxpr, bconsts + carry)
        if out is None:
            return None
        new = [a or b for a, b in zip(carry, out)]
        if new == carry:
            break
        carry = new
    else:
        return None
    pred = out_batched(cond_jaxpr, cconsts + carry)
    if pred is None:
        return None
    return [True] * len(carry) if pred[0] else carry


# ---- the wrapped batching rules ---------------------------------------------------------------------------------

def _check() -> bool:
    return os.environ.get("JAXDIP_CHECK_CARRY_BATCHING", "") not in ("", "0")


@contextlib.contextmanager
def _memo() -> Iterator[None]:
    """Loops nested in a loop body are read once per batching of the outermost loop, not once per level."""
    outer = getattr(_state, "memo", None) is None
    if outer:
        _state.memo = {}
    try:
        yield
    finally:
        if outer:
            _state.memo = None


def _broadcast(batching, axis_data, args, dims, idx: list[int]):
    args, dims = list(args), list(dims)
    for i in idx:
        args[i] = batching.broadcast(args[i], axis_data.size, 0, axis_data.explicit_mesh_axis)
        dims[i] = 0
    return args, dims


def _scan_carry(ins, *, jaxpr, num_consts, num_carry, **_):
    """(index of the scan's first carried operand, its carry after the fixed point or None)."""
    return num_consts, _scan_out(jaxpr, ins, num_consts, num_carry)[0]


def _while_loop_carry(ins, *, cond_jaxpr, body_jaxpr, cond_nconsts, body_nconsts, **_):
    """The same for a while loop. JAX puts the carry's batch axis after the predicate's: only a scalar predicate
    keeps it at 0, where the broadcast puts it."""
    carry = _while_carry(cond_jaxpr, body_jaxpr, ins, cond_nconsts, body_nconsts)
    return cond_nconsts + body_nconsts, carry if not cond_jaxpr.out_avals[0].shape else None


def _wrap(orig, batching, predict):
    """JAX's batching rule ``orig`` of a loop, given beforehand the carry that ``predict`` reads off the program."""
    def rule(axis_data, args, dims, **params):
        if not _on():
            return orig(axis_data, args, dims, **params)
        with _memo():  # for the whole batching: the loops nested in this body are read from it
            ins = [d is not None for d in dims]
            first, carry = predict(ins, **params)
            if _check() and carry is not None:
                _, ref = orig(axis_data, args, dims, **params)
                want = [d is not None for d in ref[:len(carry)]]
                if carry != want:
                    raise AssertionError(f"carry batching predicted {carry}, JAX's fixed point {want}")
            if carry is not None:
                idx = [first + i for i, b in enumerate(carry) if b and not ins[first + i]]
                args, dims = _broadcast(batching, axis_data, args, dims, idx)
            return orig(axis_data, args, dims, **params)

    return rule


def install() -> bool:
    """Wrap JAX's scan and while batching rules (once); False, leaving JAX as it is, where this JAX's rules do not
    have the shape this module was written against."""
    global _installed
    if _installed:
        return True
    try:
        from jax._src.interpreters import batching
        from jax._src.lax.control_flow import loops

        scan_rule = batching.fancy_primitive_batchers[loops.scan_p]
        while_rule = batching.fancy_primitive_batchers[loops.while_p]
        want = {scan_rule: ["axis_data", "args", "dims", "reverse", "length", "jaxpr", "num_consts", "num_carry"],
                while_rule: ["axis_data", "args", "dims", "cond_nconsts", "cond_jaxpr", "body_nconsts",
                             "body_jaxpr"]}
        for f, names in want.items():
            if list(inspect.signature(f).parameters)[:len(names)] != names:
                return False
        if list(inspect.signature(batching.broadcast).parameters)[:4] != ["x", "sz", "axis", "mesh_axis"]:
            return False
        batching.fancy_primitive_batchers[loops.scan_p] = _wrap(scan_rule, batching, _scan_carry)
        batching.fancy_primitive_batchers[loops.while_p] = _wrap(while_rule, batching, _while_loop_carry)
    except (ImportError, AttributeError, KeyError, TypeError, ValueError):
        return False
    _installed = True
    return True
