"""split_lanes: the keys of jax.random.split, computed one by one (the loop's period keys depend on it)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxdip as jd


@pytest.mark.parametrize("n", [1, 2, 4, 5, 7])
def test_split_lanes_equal_split(n):
    keys = jax.random.split(jax.random.PRNGKey(2024), 16)
    lanes = jax.jit(jax.vmap(lambda k: jnp.stack(jd.split_lanes(k, n))))(keys)
    ref = jax.vmap(lambda k: jax.random.split(k, n))(keys)
    np.testing.assert_array_equal(np.asarray(lanes), np.asarray(ref))


def test_split_lanes_fall_back_to_split_without_the_partitionable_layout():
    key = jax.random.PRNGKey(7)
    old = jax.config.jax_threefry_partitionable
    try:
        jax.config.update("jax_threefry_partitionable", False)
        lanes = np.asarray(jnp.stack(jd.split_lanes(key, 5)))
        np.testing.assert_array_equal(lanes, np.asarray(jax.random.split(key, 5)))
        # the old layout's split is not fold_in: the fallback is what keeps the two equal
        assert not np.array_equal(lanes[1], np.asarray(jax.random.fold_in(key, 1)))
    finally:
        jax.config.update("jax_threefry_partitionable", old)


def test_typed_keys_use_split():
    key = jax.random.key(3)
    lanes = jd.split_lanes(key, 3)
    ref = jax.random.split(key, 3)
    for a, b in zip(lanes, ref):
        np.testing.assert_array_equal(np.asarray(jax.random.key_data(a)), np.asarray(jax.random.key_data(b)))
