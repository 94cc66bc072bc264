"""``public_dir``: a module's ``__dir__`` (PEP 562) that lists its public names only.

Without it ``dir(jaxdip.sensors)`` shows what the module imported (``jax``, ``jnp``, ``eqx``) beside what it
defines; with it, ``dir`` and tab completion show ``__all__``. The names a module imports stay importable from it.
"""

from typing import Callable


def public_dir(module_globals: dict) -> Callable[[], list[str]]:
    """``__dir__ = public_dir(globals())`` after ``__all__``: reads ``__all__`` when called, so a later
    ``__all__ += [...]`` is listed too."""
    return lambda: sorted(module_globals["__all__"])
