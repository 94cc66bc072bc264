"""The compilation cache's key does not depend on who calls the experiment (jaxdip.cli._compile_cache): the same
program lowered under two different Python call stacks gives the same module, locations included."""

import jax
import jax.numpy as jnp


def _lowered() -> str:
    def program(x):  # a new function each time: JAX's trace cache would hand back the first caller's locations
        return jnp.sin(x) @ x.T

    return jax.jit(program).lower(jnp.ones((3, 3))).as_text(debug_info=True)


def _deeper() -> str:  # another caller: the outer frames differ, the frame that makes the operations does not
    return (lambda: _lowered())()


def test_the_key_ignores_the_outer_call_stack():
    assert jax.config.jax_include_full_tracebacks_in_locations is False  # set with the cache (conftest, the CLI)
    assert _lowered() == _deeper()
    jax.config.update("jax_include_full_tracebacks_in_locations", True)
    try:  # JAX's default: the whole stack is in the module, so the two callers' keys differ
        assert _lowered() != _deeper()
    finally:
        jax.config.update("jax_include_full_tracebacks_in_locations", False)
