"""bench's two files, ``x.json`` and its figure ``x.png``: each refusal gives exit 2 and one line, before the bench
runs (it is replaced by a stub that fails the test if called), and leaves the working folder and a victim folder
beside it as they were."""

from __future__ import annotations

import hashlib
import json
import os

import pytest

import outdir_world as W
from outdir_world import refused

world = W.world  # the shared fixture



@pytest.fixture
def no_bench(monkeypatch):
    import jaxdip.bench.scoreboard

    def never(**k):
        raise AssertionError("the bench ran")

    monkeypatch.setattr(jaxdip.bench.scoreboard, "run_bench", never)


def _bench_files(world, png=b"\x89PNG ours"):
    (world / "b.png").write_bytes(png)
    (world / "b.json").write_text(json.dumps({"tool": "jaxdip bench",
                                              "figure": {"file": "b.png", "sha256": hashlib.sha256(png).hexdigest()}}))


def test_bench_keeps_the_users_png(world, capsys, no_bench):
    (world / "b.png").write_bytes(b"\x89PNG my figure")
    assert "b.png" in refused(world, capsys, ["bench", "--quick", "--out", "b.json"])


def test_bench_keeps_its_png_once_edited(world, capsys, no_bench):
    _bench_files(world)
    (world / "b.png").write_bytes(b"\x89PNG annotated")
    refused(world, capsys, ["bench", "--quick", "--out", "b.json"])


def test_bench_png_without_its_json(world, capsys, no_bench):
    _bench_files(world)
    os.remove(world / "b.json")
    refused(world, capsys, ["bench", "--quick", "--out", "b.json"])


@pytest.mark.parametrize("kind", ["symlink", "fifo", "folder"])
def test_bench_png_not_a_file(world, capsys, no_bench, kind):
    _bench_files(world)
    os.remove(world / "b.png")
    {"symlink": lambda: os.symlink(world / "victim" / "thesis.tex", world / "b.png"),
     "fifo": lambda: os.mkfifo(world / "b.png"), "folder": lambda: os.mkdir(world / "b.png")}[kind]()
    refused(world, capsys, ["bench", "--quick", "--out", "b.json"])


def test_bench_json_is_a_fifo(world, capsys, no_bench):
    os.mkfifo(world / "b.json")
    refused(world, capsys, ["bench", "--quick", "--out", "b.json"])


def test_bench_missing_parent_before_the_bench(world, capsys, no_bench):
    assert "does not exist" in refused(world, capsys, ["bench", "--quick", "--out", "nowhere/b.json"])


def test_bench_out_named_like_its_figure(world, capsys, no_bench):
    assert ".json" in refused(world, capsys, ["bench", "--quick", "--out", "b.PNG"])


def test_bench_may_replace_its_own_files(world):
    from jaxdip.bench.scoreboard import check_outputs

    _bench_files(world)
    check_outputs(str(world / "b.json"))
