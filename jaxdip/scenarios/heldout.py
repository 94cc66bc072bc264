"""Held-out scenarios of the tuning targets: each Monte Carlo seed draws its own scenario (initial state, sensor
bias, disturbance size) by scaling chosen leaves of its trial by 1 + U(-s, s), from a stream of its own key that
none of the trial's draws uses (see ``jaxdip.scenarios.tune_targets`` and the ``tune`` experiment)."""

from __future__ import annotations

from typing import Any, Optional

import equinox as eqx
import jax
import jax.numpy as jnp

# the held-out scenario of seed i is drawn from fold_in(key_i, SCENARIO_TAG): a stream none of the trial's own
# draws uses (they take fold_in(key_i, 0) and splits of key_i), so a seed's noise is the same with or without
# scenario variation, and the paper's, tuned and random-search values meet the same scenarios (paired)
SCENARIO_TAG = 0x5CE9A410
SCENARIO_KINDS = ("x0", "bias", "disturbance")


class ScenarioDraw(eqx.Module):
    """A Monte Carlo trial ``fn(key, *rest)`` whose scenario is drawn per seed: every leaf that a ``where``
    selects is multiplied by 1 + U(-s, s) (independently per entry), from ``fold_in(key, SCENARIO_TAG)``; the
    trial then runs with its own key unchanged."""

    fn: Any
    wheres: tuple = eqx.field(static=True)
    spreads: tuple = eqx.field(static=True)

    def __call__(self, key, *rest):
        ks = jax.random.split(jax.random.fold_in(key, SCENARIO_TAG), len(self.wheres))
        fn = self.fn
        for where, s, k in zip(self.wheres, self.spreads, ks):
            leaf = where(fn)
            fn = eqx.tree_at(where, fn, leaf * scenario_factor(k, s, jnp.shape(leaf)))
        return fn(key, *rest)


def scenario_factor(key, spread: float, shape=()) -> jax.Array:
    """1 + U(-spread, spread), per entry of ``shape``."""
    return 1.0 + spread * jax.random.uniform(key, shape, minval=-1.0, maxval=1.0)


def with_scenarios(fn, leaves: dict, spreads: Optional[dict]):
    """``fn`` drawing its scenario per seed (``ScenarioDraw``) over the ``leaves`` ({kind: [where, ...]}) whose
    kind has a positive spread; ``fn`` itself when none has (the tuning scenario, unchanged)."""
    pairs = [(w, float(spreads[k])) for k, ws in leaves.items() for w in ws if spreads and spreads.get(k, 0.0) > 0]
    if not pairs:
        return fn
    return ScenarioDraw(fn, tuple(w for w, _ in pairs), tuple(s for _, s in pairs))
