"""jaxdip: differentiable, vectorised estimation and control of underactuated pendulums.

Importing jaxdip turns on JAX's float64 mode (``jax_enable_x64``): the documents' methods need it
(P with singular values near 1e6, MHE weights of order 1e4). Code that wants float32 passes
explicit float32 arrays; nothing in jaxdip silently downcasts.
"""

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

from jaxdip import plants, sim  # noqa: E402,F401
