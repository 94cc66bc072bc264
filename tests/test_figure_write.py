"""The runner lays out and writes every figure of a run in one draw: ``tight_layout`` leaves a placeholder layout
engine on the figure, and ``savefig`` answers any engine with a whole extra draw pass before the real one, so the
runner drops the engine after laying out. The file must be the figure a plain ``tight_layout`` + ``savefig`` at
the same resolution gives, pixel for pixel."""

from __future__ import annotations

import dataclasses
import io

import matplotlib
import numpy as np
import pytest
from matplotlib.figure import Figure

import outdir_world as W
from jaxdip.runner.experiment import FIGURE_DPI

world = W.world  # the shared fixture


def _figure(label: int) -> Figure:
    fig = Figure(figsize=(4, 3))
    axes = fig.subplots(2, 1)
    axes[0].plot(np.linspace(0, 1, 50), np.sin(np.linspace(0, 6, 50)), label="sin")
    axes[0].set_ylabel(r"$\alpha$ (rad)")
    axes[0].legend()
    axes[1].semilogy([1, 10, 100], label=str(label))
    axes[1].set_xlabel("a long label that tight_layout must make room for")
    fig.suptitle("two panels")
    return fig


def _pixels(png: bytes) -> np.ndarray:
    return matplotlib.image.imread(io.BytesIO(png), format="png")


def test_each_figure_is_drawn_once_and_gives_the_two_pass_pixels(world, monkeypatch):
    import jaxdip.runner as runner
    from jaxdip.runner import Outcome

    def run(cfg, ctx):
        return Outcome(results={"calls": 1}, report="stub report", figures={"fig": _figure(1)})

    real_get = runner.get
    monkeypatch.setattr(runner, "get", lambda exp_id: dataclasses.replace(real_get(exp_id), run=run))
    draws = []
    original = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda self, r: (draws.append(1), original(self, r))[1])
    assert W.run() == 0
    assert len(draws) == 1  # two before: the placeholder engine's extra pass, then the real one
    monkeypatch.setattr(Figure, "draw", original)

    # the same figure laid out at the resolution it is saved in and saved the plain way, in two draws
    ref = _figure(1)
    ref.set_dpi(FIGURE_DPI)
    ref.tight_layout()
    buf = io.BytesIO()
    ref.savefig(buf, format="png", dpi=FIGURE_DPI)
    got = (world / "dest" / "fig.png").read_bytes()
    np.testing.assert_array_equal(_pixels(got), _pixels(buf.getvalue()))


@pytest.mark.parametrize("engine", ["tight", "constrained"])
def test_savefig_draws_twice_under_any_layout_engine(engine, monkeypatch):
    """The matplotlib behaviour the runner works around: if this fails, savefig no longer draws twice and the
    runner's ``set_layout_engine(None)`` is no longer needed."""
    fig = _figure(1)
    fig.set_layout_engine(engine)
    draws = []
    original = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda self, r: (draws.append(1), original(self, r))[1])
    fig.savefig(io.BytesIO(), format="png", dpi=50)
    assert len(draws) == 2
