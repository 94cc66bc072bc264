"""Key arithmetic shared by the loop and its components."""

from __future__ import annotations

import jax


from jaxdip._public import public_dir

__all__ = ["split_lanes"]
__dir__ = public_dir(globals())


def split_lanes(key, n: int) -> tuple:
    """``jax.random.split(key, n)`` as a tuple of ``n`` keys, each computed on its own, so that the compiled
    program keeps only the keys a loop uses (a period's split into five feeds one sensor in most loops).

    Under JAX's partitionable threefry (the default since JAX 0.5) ``split(key, n)[j]`` is ``fold_in(key, j)``
    bit for bit (tested); with another generator or the old threefry layout this is ``split`` itself."""
    if (jax.config.jax_threefry_partitionable and jax.config.jax_default_prng_impl == "threefry2x32"
            and not jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)):
        return tuple(jax.random.fold_in(key, j) for j in range(n))
    return tuple(jax.random.split(key, n))
