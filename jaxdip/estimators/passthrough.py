"""The trivial estimator: the measurement is the estimate (full-state measurement)."""

from jaxdip.sim.component import stateless

passthrough = stateless(lambda params, inp, key, k: inp[0])
