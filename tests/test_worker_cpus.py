"""Each worker of a parallel reproduce (and each pytest-xdist worker) keeps to its own block of CPUs."""

import os
import subprocess
import sys

import pytest

from jaxdip.reproduce_pool import cpu_blocks

needs_affinity = pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="no CPU affinity on this OS")


@needs_affinity
def test_blocks_split_this_process_cpus_into_disjoint_near_equal_parts():
    cpus = sorted(os.sched_getaffinity(0))
    for n in range(2, len(cpus) + 1):
        blocks = cpu_blocks(n)
        assert len(blocks) == n
        assert sorted(c for b in blocks for c in b) == cpus  # every CPU once, none twice
        assert max(map(len, blocks)) - min(map(len, blocks)) <= 1
    assert cpu_blocks(1) == []  # one worker keeps every CPU
    assert cpu_blocks(len(cpus) + 1) == []  # more workers than CPUs: no pinning rather than shared blocks


@needs_affinity
def test_worker_keeps_to_the_cpus_its_parent_gives_it():
    cpu = min(os.sched_getaffinity(0))
    code = ("import os; from jaxdip.reproduce_worker import keep_to_cpus; keep_to_cpus(); "
            "print(sorted(os.sched_getaffinity(0)))")
    env = dict(os.environ, JAXDIP_WORKER_CPUS=str(cpu))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str([cpu])
    env["JAXDIP_WORKER_CPUS"] = "not-a-cpu"  # a bad value runs unpinned rather than failing the worker
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(sorted(os.sched_getaffinity(0)))


@needs_affinity
def test_this_xdist_worker_keeps_to_its_share_of_the_cpus():
    worker, count = os.environ.get("PYTEST_XDIST_WORKER"), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    cores = os.cpu_count() or 1
    if not worker or not 2 <= count <= cores:
        pytest.skip("not under pytest-xdist with at least as many CPUs as workers")
    assert len(os.sched_getaffinity(0)) <= -(-cores // count)  # conftest pinned this worker before JAX started
