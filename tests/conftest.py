import os
import subprocess
import sys
import tempfile
from types import SimpleNamespace

import pytest

os.environ.setdefault("JAXDIP_NO_PROGRESS", "1")
# the CLI's on-disk compilation cache goes to a throwaway folder, not the user's ~/.cache
os.environ.setdefault("JAXDIP_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"jaxdip-test-xla-{os.getuid()}"))

import jaxdip  # noqa: E402,F401  (enables float64 before any test builds an array)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# The smallest dip-lqr run that still exercises the whole CLI path: 6 seeds (not a multiple of 4 devices, so the
# distributed run pads), 200 periods, every period recorded.
TINY_DIP_LQR = ["run", "dip-lqr", "--quick", "--seeds", "6", "--set", "duration=0.2", "--set", "record_every=1"]


@pytest.fixture(scope="session")
def dip_lqr_uncached(tmp_path_factory):
    """``jaxdip run dip-lqr`` (TINY_DIP_LQR) in a child process with ``--no-compile-cache`` and JAXDIP_CACHE_DIR
    pointed at a folder of its own that does not exist yet.

    One child process (JAX import plus a cold compilation) shared by the tests that need this run: the CLI's
    output contract, the compilation-cache test (which reuses ``cache``) and the one-process reference of the
    two-process ``--distributed`` run.
    """
    root = tmp_path_factory.mktemp("dip-lqr-tiny")
    cache, out = root / "xla", root / "a"
    env = dict(os.environ, JAXDIP_NO_PROGRESS="1", JAXDIP_CACHE_DIR=str(cache))
    proc = subprocess.run([sys.executable, "-m", "jaxdip.cli", *TINY_DIP_LQR, "--no-compile-cache", "--out",
                           str(out)], capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)
    return SimpleNamespace(args=list(TINY_DIP_LQR), root=root, cache=cache, out=out, proc=proc, env=env,
                           cache_existed=cache.exists())
