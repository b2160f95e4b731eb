"""Rendering: static pictures, animations, attention scores and gymnasium rgb_array frames."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from crowdplan.algos.orca_planner import OrcaPlanner
from crowdplan.config import WorldConfig
from crowdplan.evaluation import Trace, run_episodes
from crowdplan.sim import render
from crowdplan.sim.world import World

CONFIG = WorldConfig(humans=3, time_limit=3.0)  # at most 12 steps


@pytest.fixture(scope="module")
def trace() -> Trace:
    record = run_episodes(OrcaPlanner(), CONFIG, [1000], record_traces=True)[0]
    assert record.trace is not None and record.steps >= 2
    return record.trace


def scored(trace: Trace) -> Trace:
    """The trace with fake attention scores, distinct per human and step."""
    steps, n = len(trace.robot_pos) - 1, trace.human_pos.shape[1]
    scores = np.random.default_rng(0).dirichlet(np.ones(n), size=steps)
    return dataclasses.replace(trace, scores=scores)


def texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]


def test_png_written(tmp_path, trace):
    path = render.save_render(trace, tmp_path / "episode.png", title="ORCA")
    assert path == tmp_path / "episode.png"
    with Image.open(path) as image:
        assert image.format == "PNG"
        assert image.width > 200 and image.height > 200
    assert [p.name for p in tmp_path.iterdir()] == ["episode.png"]  # no temporary left over


def test_gif_has_one_frame_per_state(tmp_path, trace):
    path = render.save_render(scored(trace), tmp_path / "sub" / "episode.gif", title="ORCA")
    with Image.open(path) as image:
        assert image.format == "GIF"
        assert image.n_frames == len(trace.robot_pos)  # T steps -> T + 1 states
    assert [p.name for p in path.parent.iterdir()] == ["episode.gif"]


def test_scores_written_next_to_humans(trace):
    fake = scored(trace)
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    render.draw_trace(ax, fake, upto=1)
    shown = texts(ax)
    for value in fake.scores[1]:
        assert f"{value:.2f}" in shown
    # Without scores (or with show_scores False) no score label is drawn.
    ax.cla()
    render.draw_trace(ax, fake, upto=1, show_scores=False)
    assert not any(f"{value:.2f}" in texts(ax) for value in fake.scores[1])


def test_time_stamps(trace):
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    render.draw_trace(ax, trace, stamp_every=4)
    shown = texts(ax)
    assert "0.0" in shown
    if len(trace.robot_pos) > 5:
        assert f"{4 * trace.dt:.1f}" in shown
    with pytest.raises(ValueError, match="upto"):
        render.draw_trace(ax, trace, upto=len(trace.robot_pos))


def test_bad_suffix(tmp_path, trace):
    with pytest.raises(ValueError, match=r"'\.jpg'.*\.gif, \.png"):
        render.save_render(trace, tmp_path / "episode.jpg")
    assert not list(tmp_path.iterdir())


def test_scene_rgb():
    world = World(CONFIG, 2)
    world.reset([1000, 1001])
    history = [(world.robot_pos[1].copy(), world.human_pos[1].copy())]
    for _ in range(3):
        world.step(np.full(2, 5))
        history.append((world.robot_pos[1].copy(), world.human_pos[1].copy()))
    image = render.scene_rgb(world, 1, history)
    assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8
    assert image.shape[0] > 100 and image.shape[1] > 100
    assert image.min() < 100 < 200 < image.max()  # something is drawn on a light background
    assert render.scene_rgb(world, 0, []).shape == image.shape
