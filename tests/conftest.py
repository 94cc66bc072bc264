import os
import subprocess
import sys
import tempfile
from types import SimpleNamespace

import pytest


def _keep_worker_to_its_cpus() -> None:
    """Under pytest-xdist, keep worker i to its share of the CPUs (the CLI runs it starts inherit it), before JAX
    starts: XLA sizes its thread pool from the CPUs a process may use, and two workers whose pools share the cores
    wait on each other's descheduled threads at every kernel (``jaxdip.reproduce_pool.cpu_blocks``)."""
    from jaxdip.reproduce_pool import cpu_blocks
    from jaxdip.reproduce_worker import keep_to_cpus

    worker, count = os.environ.get("PYTEST_XDIST_WORKER", ""), os.environ.get("PYTEST_XDIST_WORKER_COUNT", "")
    if worker.startswith("gw") and count.isdigit():
        blocks = cpu_blocks(int(count))
        if blocks:
            keep_to_cpus(",".join(map(str, blocks[int(worker[2:]) % len(blocks)])))


_keep_worker_to_its_cpus()
os.environ.setdefault("JAXDIP_NO_PROGRESS", "1")
# the CLI's on-disk compilation cache goes to a throwaway folder, not the user's ~/.cache
os.environ.setdefault("JAXDIP_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"jaxdip-test-xla-{os.getuid()}"))

import jaxdip  # noqa: E402,F401  (enables float64 before any test builds an array)
from jaxdip.cli import _compile_cache  # noqa: E402
from jaxdip import xla_flags  # noqa: E402

# Most of the suite's time is XLA compiling small programs that then run for milliseconds: the whole suite (its
# own jits, eager operations, the CLI runs it starts) compiles at the "fast" effort, which halved its cold wall
# time. JAXDIP_TEST_EFFORT=full runs it at XLA's defaults, as full experiment runs compile.
xla_flags.set_effort(os.environ.setdefault("JAXDIP_TEST_EFFORT", "fast"))


def host_devices_flags(n: int) -> str:
    """XLA_FLAGS for a child process with ``n`` host CPU devices, keeping the suite's compile effort."""
    return f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={n}".strip()


# Compiled programs go to that folder from the first test on, as in a CLI run: the test processes (pytest's
# workers) and the CLI runs the tests start share what one of them compiled, and a second run of the suite on
# the same machine compiles little.
_compile_cache(True)
# ... but not the traced programs (jaxdip.program_cache) in the test processes themselves: the suite starts cold,
# where a stored program costs about 9% more than a direct call (it is lowered twice: exported, then called), and
# few of its programs repeat. The CLI runs the tests start keep it, as a user's runs do, and
# tests/test_program_cache.py turns it on where it checks it.
from jaxdip import program_cache  # noqa: E402

program_cache.enable(None)


@pytest.fixture(autouse=True)
def _no_program_cache_after_a_test():
    """An in-process ``cli.main(["run", ...])`` turns the program cache on for the whole process, as a CLI run
    should; in the suite that would last into every later test of the worker, which would then trace and lower
    each of its programs twice (exported, then called): 38 s of the suite's tracing and lowering, measured."""
    yield
    if program_cache.enabled_folder() is not None:
        program_cache.enable(None)


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# The files that take longest (summed over their tests, measured with an empty compilation cache), longest first.
# pytest-xdist's --dist loadfile hands files to the workers in collection order (pyproject passes
# --no-loadscope-reorder: its default order, most tests first, put these few-test files last, where one of them
# kept a worker busy for half a minute while the others had nothing left). Starting them first lets the many
# short files fill in around them. A file missing here only runs later; the order changes no result.
LONGEST_FIRST = (
    "test_tutorial.py", "test_kill_resume.py", "test_eki.py", "test_cli.py", "test_cli_faults.py",
    "test_cli_distributed_faults.py", "test_driver.py",
    "test_eki_dip.py", "test_dip_cpx_ldf.py", "test_lorenz_mhe.py", "test_tune.py", "test_immune_levelset.py",
    "test_weighted_mhe.py", "test_simulate.py", "test_search_steps.py", "test_dip_mpc.py",
    "test_immune_autonomous.py", "test_lorenz_components.py", "test_mpc.py", "test_effort.py",
    "test_readme_example.py", "test_rwp_theory.py", "test_spread.py",
)


def pytest_collection_modifyitems(config, items):
    gone = [name for name in LONGEST_FIRST if not os.path.exists(os.path.join(ROOT, "tests", name))]
    if gone:  # a renamed file would silently drop back to the end
        raise pytest.UsageError(f"conftest.LONGEST_FIRST names files that are not there: {', '.join(gone)}")
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order



# The smallest dip-lqr run that still exercises the whole CLI path: 6 seeds (not a multiple of 4 devices, so the
# distributed run pads), 200 periods, every period recorded.
TINY_DIP_LQR = ["run", "dip-lqr", "--quick", "--seeds", "6", "--set", "duration=0.2", "--set", "record_every=1"]


class Child:
    """A ``jaxdip`` child process started now and waited for when its result is first needed, so that tests can
    overlap independent runs (each is mostly single-threaded tracing and compilation)."""

    def __init__(self, argv, env, cwd=ROOT):
        self.proc = subprocess.Popen([sys.executable, "-m", "jaxdip.cli", *argv], cwd=cwd, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.stdout = self.stderr = None

    def wait(self, timeout=600) -> "Child":
        if self.stdout is None:
            try:
                self.stdout, self.stderr = self.proc.communicate(timeout=timeout)
            finally:
                self.kill()
        return self

    @property
    def returncode(self) -> int:
        return self.wait().proc.returncode

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture(scope="session")
def dip_lqr_uncached(tmp_path_factory):
    """``jaxdip run dip-lqr`` (TINY_DIP_LQR) in a child process with ``--no-compile-cache`` and JAXDIP_CACHE_DIR
    pointed at a folder (``cache_off``) that does not exist.

    One child process (JAX import plus a cold compilation) shared by the tests that need this run: the CLI's
    output contract, the compilation-cache test and the one-process reference of the two-process
    ``--distributed`` run, all in test_cli.py (pytest-xdist makes a session fixture once per worker, and runs a
    file in one worker). ``proc`` is a started :class:`Child`; ``proc.wait()`` before reading ``out``; ``Child`` starts
    more runs.
    """
    root = tmp_path_factory.mktemp("dip-lqr-tiny")
    cache_off = root / "xla-off"
    env = dict(os.environ, JAXDIP_NO_PROGRESS="1", JAXDIP_CACHE_DIR=str(cache_off))
    child = Child([*TINY_DIP_LQR, "--no-compile-cache", "--out", str(root / "a")], env)
    yield SimpleNamespace(args=list(TINY_DIP_LQR), root=root, cache_off=cache_off, out=root / "a", proc=child,
                          Child=Child)
    child.kill()
