"""The public surface: every public module declares ``__all__``, every name in it resolves, ``dir()`` shows those
names only (no ``jax``, ``jnp``, ``eqx``, ``np``, ``annotations``), and one name means one object across the public
modules (a name in two of them is the same object re-exported, never two different things).

Public: the root, the engine, plants, sim, estimators, control, tune, search, stats and dataset, with all their modules
(found by walking the packages, so a new module is public by default). Not public: the command line and its
workers, the experiment runner, the scenarios, theory and immune layers (reached by experiments), the bench, and
the foundations other than stats (output folders, checkpoints, configs, progress, messages, XLA flags), whose
users are the layers above, not a user's script.
"""

import importlib
import pkgutil

import pytest

import jaxdip

PUBLIC_PACKAGES = ["jaxdip.engine", "jaxdip.plants", "jaxdip.sim", "jaxdip.estimators", "jaxdip.control",
                   "jaxdip.tune", "jaxdip.search"]
PUBLIC_MODULES = ["jaxdip", "jaxdip.stats", "jaxdip.dataset"]
NOT_PUBLIC = ["jaxdip.bench", "jaxdip.runner", "jaxdip.scenarios", "jaxdip.theory", "jaxdip.immune", "jaxdip.outdir",
              "jaxdip.checkpoint", "jaxdip.cli", "jaxdip.cli_args", "jaxdip.cli_compare", "jaxdip.cli_config",
              "jaxdip.cli_errors", "jaxdip.cli_sweep", "jaxdip.gc_policy",
              "jaxdip.config", "jaxdip.config_toml", "jaxdip.distributed", "jaxdip.messages", "jaxdip.progress",
              "jaxdip.reproduce_pool", "jaxdip.reproduce_worker", "jaxdip.resources", "jaxdip.xla_flags",
              "jaxdip.program_cache", "jaxdip.program_key"]


def public_modules() -> list[str]:
    names = list(PUBLIC_MODULES)
    for pkg in PUBLIC_PACKAGES:
        names.append(pkg)
        for info in pkgutil.walk_packages(importlib.import_module(pkg).__path__, pkg + "."):
            if not any(part.startswith("_") for part in info.name.split(".")):
                names.append(info.name)
    return names


MODULES = public_modules()


def test_every_module_of_the_package_is_classified():
    # a new top-level module or package must be put in one list or the other
    top = {f"jaxdip.{m.name}" for m in pkgutil.iter_modules(jaxdip.__path__) if not m.name.startswith("_")}
    assert top == set(PUBLIC_PACKAGES) | set(PUBLIC_MODULES[1:]) | set(NOT_PUBLIC)
    assert len(MODULES) > 50


@pytest.mark.parametrize("name", MODULES)
def test_all_resolves_and_dir_shows_only_it(name):
    mod = importlib.import_module(name)
    assert isinstance(getattr(mod, "__all__", None), list), f"{name} has no __all__"
    assert len(set(mod.__all__)) == len(mod.__all__), f"{name}.__all__ repeats a name"
    missing = [n for n in mod.__all__ if not hasattr(mod, n)]
    assert not missing, f"{name}.__all__ names what it does not have: {missing}"
    assert dir(mod) == sorted(mod.__all__)
    assert not {"jax", "jnp", "eqx", "np", "annotations", "public_dir"} & set(dir(mod))
    assert all(not n.startswith("_") for n in mod.__all__)


def test_one_name_means_one_object():
    seen: dict[str, tuple[str, object]] = {}
    clashes = []
    for name in MODULES:
        mod = importlib.import_module(name)
        for n in mod.__all__:
            obj = getattr(mod, n)
            if n in seen and seen[n][1] is not obj:
                clashes.append(f"{n}: {seen[n][0]}.{n} is not {name}.{n}")
            seen.setdefault(n, (name, obj))
    assert not clashes, "\n".join(clashes)


def test_the_root_is_clean():
    import jaxdip as jd

    names = dir(jd)
    assert names == sorted(jd.__all__)
    assert {"summary", "stats", "FunctionPlant", "Loop", "monte_carlo", "plants", "sensors"} <= set(names)
    assert jd.sensors is importlib.import_module("jaxdip.sim.sensors")
    assert jd.metrics is importlib.import_module("jaxdip.engine.metrics")
    assert jd.__version__  # dunders stay reachable though not listed
