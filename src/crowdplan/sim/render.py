"""Matplotlib drawings of episodes: static pictures, animations and gymnasium ``rgb_array`` frames.

Everything draws on ``matplotlib.figure.Figure`` objects with the Agg canvas, never through
``pyplot``, so that rendering neither needs a display nor touches global figure state. Import this
module lazily (it imports matplotlib).

The picture of a trace (``draw_trace``):

- the robot as a filled gold disc, its goal as a red star;
- each human as a circle in its own colour, its goal as a small cross of that colour;
- trajectories as lines, with discs at every ``stamp_every``-th step labelled with the time in
  seconds (faded, so that the current positions stand out);
- per-human scores (the policy's attention weights) of the current step, when the trace has
  them: written next to each human and shading the human's disc (darker = larger score).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from matplotlib.lines import Line2D
from matplotlib.patches import Circle

from crowdplan.evaluation import Trace
from crowdplan.io import atomic_write

__all__ = ["RENDER_SUFFIXES", "draw_trace", "save_gif", "save_png", "save_render", "scene_rgb"]

RENDER_SUFFIXES = (".gif", ".png")

ROBOT_COLOR = "#f2b01e"
ROBOT_EDGE = "#1a1a1a"
ROBOT_GOAL_COLOR = "#d62728"
SCORE_CMAP = "Reds"
# tab10 without orange and olive (too close to the robot's gold) and red (the robot's goal).
HUMAN_COLORS = (
    "#1f77b4",
    "#2ca02c",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#17becf",
    "#393b79",
)
MARGIN = 0.8  # metres around the scene


def human_colors(n: int) -> list:
    """One distinct colour per human (a fixed palette up to 8, a colormap beyond)."""
    if n <= len(HUMAN_COLORS):
        return list(HUMAN_COLORS[:n])
    from matplotlib import colormaps

    cmap = colormaps["turbo"]
    return [cmap(x) for x in np.linspace(0.05, 0.95, n)]


def _score_norm(trace: Trace) -> Normalize:
    """Scores shade from 0 (white) to the largest score of the episode (darkest)."""
    top = float(np.nanmax(trace.scores)) if trace.scores is not None and trace.scores.size else 1.0
    return Normalize(0.0, top if np.isfinite(top) and top > 0 else 1.0)


def scene_limits(trace: Trace) -> tuple[tuple[float, float], tuple[float, float]]:
    """Square axis limits covering every position and goal of the episode, plus a margin."""
    points = [trace.robot_pos.reshape(-1, 2), trace.robot_goal.reshape(1, 2)]
    if trace.human_pos.size:
        points += [trace.human_pos.reshape(-1, 2), trace.human_goal.reshape(-1, 2)]
    pts = np.concatenate(points)
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2
    half = max(float((hi - lo).max()) / 2, 1.0) + MARGIN
    return (centre[0] - half, centre[0] + half), (centre[1] - half, centre[1] + half)


class _Style:
    """Per-trace drawing constants shared by the static picture and the animation."""

    def __init__(self, trace: Trace, show_scores: bool) -> None:
        self.n = trace.human_pos.shape[1] if trace.human_pos.ndim == 3 else 0
        self.colors = human_colors(self.n)
        self.r_robot = float(trace.robot_radius)
        self.radii = np.broadcast_to(np.asarray(trace.human_radius, dtype=float), (self.n,))
        self.scores = None
        if show_scores and _has_scores(trace) and self.n:
            from matplotlib import colormaps

            self.scores = np.asarray(trace.scores, dtype=float)
            self.norm = _score_norm(trace)
            self.cmap = colormaps[SCORE_CMAP]


def _draw_static(ax, trace: Trace, style: _Style) -> None:
    """Goals, limits, labels and grid: everything that does not change during the episode."""
    ax.plot(
        *trace.robot_goal,
        marker="*",
        markersize=15,
        color=ROBOT_GOAL_COLOR,
        markeredgecolor="black",
        markeredgewidth=0.6,
        linestyle="none",
        zorder=2,
    )
    for i in range(style.n):
        ax.plot(
            *trace.human_goal[i],
            marker="x",
            markersize=6,
            markeredgewidth=1.5,
            color=style.colors[i],
            linestyle="none",
            alpha=0.8,
            zorder=2,
        )
    xlim, ylim = scene_limits(trace)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, linewidth=0.3, alpha=0.5)


def _marker(label: str, marker: str, size: float, **style) -> Line2D:
    """A legend entry drawn as one marker (no line unless ``style`` asks for a colour)."""
    return Line2D([], [], marker=marker, markersize=size, label=label, **{"color": "none", **style})


def _legend(target, style: _Style) -> None:
    """The legend: below the axes on a constrained-layout figure (so that it never hides a
    trajectory), else in the upper right corner of the axes ``target``."""
    handles = [
        _marker("robot", "o", 8, markerfacecolor=ROBOT_COLOR, markeredgecolor=ROBOT_EDGE),
        _marker("robot goal", "*", 10, markerfacecolor=ROBOT_GOAL_COLOR, markeredgecolor="black"),
    ]
    if style.n:
        human = {"markerfacecolor": "white", "markeredgecolor": "0.35"}
        handles += [
            _marker("humans", "o", 8, markeredgewidth=1.5, **human),
            _marker("human goals", "x", 6, color="0.35", linestyle="none"),
            _marker("time stamps (s)", "o", 8, alpha=0.55, **human),
        ]
    if isinstance(target, Figure):
        target.legend(
            handles=handles,
            loc="outside lower center",
            ncols=len(handles),
            fontsize=6.5,
            frameon=False,
            handletextpad=0.2,
            columnspacing=0.9,
        )
    else:
        target.legend(handles=handles, loc="upper right", fontsize=6.5, framealpha=0.85)


def _segment_artists(ax, trace: Trace, style: _Style, a: int, b: int) -> list:
    """Trajectory lines from state a to state b."""
    out = [
        ax.add_artist(
            Line2D(
                trace.robot_pos[a : b + 1, 0],
                trace.robot_pos[a : b + 1, 1],
                color=ROBOT_COLOR,
                linewidth=2.0,
                zorder=3,
                solid_capstyle="round",
            )
        )
    ]
    for i in range(style.n):
        out.append(
            ax.add_artist(
                Line2D(
                    trace.human_pos[a : b + 1, i, 0],
                    trace.human_pos[a : b + 1, i, 1],
                    color=style.colors[i],
                    linewidth=1.2,
                    alpha=0.8,
                    zorder=3,
                    solid_capstyle="round",
                )
            )
        )
    return out


def _stamp_artists(ax, trace: Trace, style: _Style, k: int) -> list:
    """Faded discs at state k labelled with its time in seconds."""
    label = f"{k * trace.dt:.1f}"
    out = []
    for i in range(style.n):
        x, y = trace.human_pos[k, i]
        out.append(
            ax.add_artist(
                Circle(
                    (x, y),
                    style.radii[i],
                    facecolor="white",
                    edgecolor=style.colors[i],
                    linewidth=0.8,
                    alpha=0.55,
                    zorder=4,
                )
            )
        )
        out.append(
            ax.text(
                x, y, label, ha="center", va="center", fontsize=5.5, color=style.colors[i], zorder=5
            )
        )
    x, y = trace.robot_pos[k]
    out.append(
        ax.add_artist(
            Circle(
                (x, y),
                style.r_robot,
                facecolor=ROBOT_COLOR,
                edgecolor=ROBOT_EDGE,
                linewidth=0.5,
                alpha=0.45,
                zorder=4,
            )
        )
    )
    out.append(
        ax.text(x, y, label, ha="center", va="center", fontsize=5.5, color="black", zorder=5)
    )
    return out


class _Current:
    """The artists of the current state (agents, scores, clock), created once and moved."""

    def __init__(self, ax, style: _Style) -> None:
        self.style = style
        bbox = {"boxstyle": "round,pad=0.2", "facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"}
        self.discs = [
            ax.add_artist(
                Circle(
                    (0.0, 0.0),
                    style.radii[i],
                    facecolor="white",
                    edgecolor=style.colors[i],
                    linewidth=2.0,
                    zorder=6,
                )
            )
            for i in range(style.n)
        ]
        self.robot = ax.add_artist(
            Circle(
                (0.0, 0.0),
                style.r_robot,
                facecolor=ROBOT_COLOR,
                edgecolor=ROBOT_EDGE,
                linewidth=1.5,
                zorder=6,
            )
        )
        self.ids = [
            ax.text(
                0.0, 0.0, str(i), ha="center", va="center", fontsize=7, fontweight="bold", zorder=7
            )
            for i in range(style.n)
        ]
        self.labels = []
        if style.scores is not None:
            self.labels = [
                ax.text(
                    0.0,
                    0.0,
                    "",
                    ha="left",
                    va="bottom",
                    fontsize=7,
                    color="black",
                    zorder=8,
                    bbox={
                        "boxstyle": "round,pad=0.15",
                        "facecolor": "white",
                        "edgecolor": style.colors[i],
                        "linewidth": 0.8,
                        "alpha": 0.85,
                    },
                )
                for i in range(style.n)
            ]
        self.clock = ax.text(
            0.02,
            0.98,
            "",
            transform=ax.transAxes,
            ha="left",
            va="top",
            fontsize=8,
            zorder=9,
            bbox=bbox,
        )

    def artists(self) -> list:
        """All artists, in drawing (z) order."""
        return [*self.discs, self.robot, *self.ids, *self.labels, self.clock]

    def place(self, trace: Trace, t: int) -> None:
        """Show state t; the scores are those of the decision taken in state t (the last
        decision for the final state)."""
        style = self.style
        scores = None if style.scores is None else style.scores[min(t, len(style.scores) - 1)]
        for i in range(style.n):
            x, y = trace.human_pos[t, i]
            self.discs[i].set_center((x, y))
            self.ids[i].set_position((x, y))
            if scores is not None:
                shade = style.norm(scores[i])
                self.discs[i].set_facecolor(style.cmap(shade))
                self.ids[i].set_color("white" if shade > 0.6 else "black")
                r = style.radii[i]
                self.labels[i].set_position((x + 0.75 * r, y + 0.75 * r))
                self.labels[i].set_text(f"{scores[i]:.2f}")
        self.robot.set_center(tuple(trace.robot_pos[t]))
        self.clock.set_text(f"t = {t * trace.dt:.2f} s")


def _check_upto(trace: Trace, upto: int | None) -> int:
    n_states = len(trace.robot_pos)
    t = n_states - 1 if upto is None else int(upto)
    if not 0 <= t < n_states:
        raise ValueError(f"upto must be in 0..{n_states - 1}, got {upto!r}")
    return t


def draw_trace(
    ax,
    trace: Trace,
    upto: int | None = None,
    show_scores: bool = True,
    stamp_every: int = 4,
) -> None:
    """Draw the episode up to state ``upto`` (0 = start, default the last state) on ``ax``.

    Args:
        ax: a matplotlib Axes (cleared by the caller if it is reused). The legend goes on the
            figure (below the axes) when the figure uses the constrained layout, else on ``ax``.
        trace: the episode (``evaluation.Trace``).
        upto: index of the state shown as "current" (0..T); trajectories and stamps stop there.
        show_scores: write and shade per-human scores when ``trace.scores`` is not None; the
            score shown at state t is the one of the decision taken in state t.
        stamp_every: a time stamp every this many steps (<= 0: none).
    """
    t = _check_upto(trace, upto)
    style = _Style(trace, show_scores)
    _draw_static(ax, trace, style)
    _segment_artists(ax, trace, style, 0, t)
    for k in range(0, t, stamp_every) if stamp_every > 0 else ():
        _stamp_artists(ax, trace, style, k)
    _Current(ax, style).place(trace, t)
    fig = ax.get_figure(root=True)
    constrained = fig is not None and isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine)
    _legend(fig if constrained else ax, style)


def _figure(size: float, dpi: int, with_scores: bool) -> tuple[Figure, object]:
    fig = Figure(
        figsize=(size + (0.7 if with_scores else 0.0), size + 0.3), dpi=dpi, layout="constrained"
    )
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def _add_colorbar(fig: Figure, ax, trace: Trace) -> None:
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable

    mappable = ScalarMappable(norm=_score_norm(trace), cmap=colormaps[SCORE_CMAP])
    bar = fig.colorbar(mappable, ax=ax, shrink=0.7, pad=0.02)
    bar.set_label("attention score", fontsize=7)
    bar.ax.tick_params(labelsize=6)


def _has_scores(trace: Trace) -> bool:
    return trace.scores is not None and np.asarray(trace.scores).size > 0


def save_png(trace: Trace, path: str | Path, title: str = "") -> Path:
    """The whole episode as one picture (final positions, time stamps along the way)."""
    path = Path(path)
    with_scores = _has_scores(trace)
    fig, ax = _figure(6.0, 110, with_scores)
    draw_trace(ax, trace)
    if with_scores:
        _add_colorbar(fig, ax, trace)
    if title:
        ax.set_title(title, fontsize=9)
    atomic_write(path, lambda f: fig.savefig(f, format="png"), mode="wb")
    return path


def _canvas_rgb(fig: Figure) -> np.ndarray:
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def animation_frames(
    trace: Trace, title: str = "", size: float = 5.0, dpi: int = 80, stamp_every: int = 4
) -> list[np.ndarray]:
    """One (H, W, 3) uint8 frame per state of the episode (T + 1 frames for T steps).

    Fast path for animations: the static part (axes, goals, legend, colour bar) is drawn once;
    each frame adds the newest trajectory segment and time stamp to a cached background (blitting)
    and draws only the agents' current discs and labels on top. Frame ``t`` looks like
    ``draw_trace(ax, trace, upto=t)``.
    """
    style = _Style(trace, True)
    fig, ax = _figure(size, dpi, style.scores is not None)
    _draw_static(ax, trace, style)
    _legend(fig, style)
    if style.scores is not None:
        _add_colorbar(fig, ax, trace)
    if title:
        ax.set_title(title, fontsize=9)
    canvas = fig.canvas
    # Solves the layout, which with an equal-aspect axes settles only on the second pass (after
    # one, the title sits above the figure's top edge); every frame then has the same geometry.
    canvas.draw()
    canvas.draw()
    fig.set_layout_engine("none")
    background = canvas.copy_from_bbox(fig.bbox)
    current = _Current(ax, style)
    frames = []
    for t in range(len(trace.robot_pos)):
        canvas.restore_region(background)
        baked = _segment_artists(ax, trace, style, t - 1, t) if t > 0 else []
        if stamp_every > 0 and t > 0 and (t - 1) % stamp_every == 0:
            baked += _stamp_artists(ax, trace, style, t - 1)
        for artist in baked:
            ax.draw_artist(artist)
            artist.remove()
        background = canvas.copy_from_bbox(fig.bbox)
        current.place(trace, t)
        for artist in current.artists():
            ax.draw_artist(artist)
        frames.append(_canvas_rgb(fig))
    return frames


def save_gif(trace: Trace, path: str | Path, title: str = "", fps: float = 4) -> Path:
    """An animation with one frame per state of the episode (T + 1 frames for T steps)."""
    from PIL import Image

    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps!r}")
    path = Path(path)
    images = [
        Image.fromarray(frame).quantize(colors=255, method=Image.Quantize.FASTOCTREE)
        for frame in animation_frames(trace, title)
    ]
    atomic_write(
        path,
        lambda f: images[0].save(
            f,
            format="GIF",
            save_all=True,
            append_images=images[1:],
            duration=int(round(1000 / fps)),
            loop=0,
            optimize=False,
        ),
        mode="wb",
    )
    return path


def save_render(trace: Trace, path: str | Path, title: str = "") -> Path:
    """Write ``path`` as an animation (``.gif``) or a static picture (``.png``)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".gif":
        return save_gif(trace, path, title)
    if suffix == ".png":
        return save_png(trace, path, title)
    raise ValueError(
        f"cannot render to a {suffix or 'suffix-less'!r} file ({path}); "
        f"valid suffixes are {', '.join(RENDER_SUFFIXES)}"
    )


def scene_rgb(world, env_index: int, history) -> np.ndarray:
    """The current scene of environment ``env_index`` of a ``World`` as an (H, W, 3) uint8 image.

    ``history`` is the list of (robot_pos (2,), human_pos (N, 2)) of the states so far (the
    current one last); an empty history draws only the current state.
    """
    cfg = world.config
    if history:
        robot_pos = np.array([np.asarray(r, dtype=float) for r, _ in history]).reshape(-1, 2)
        human_pos = np.array([np.asarray(h, dtype=float) for _, h in history]).reshape(
            len(history), cfg.humans, 2
        )
    else:
        robot_pos = world.robot_pos[env_index][None].copy()
        human_pos = world.human_pos[env_index][None].copy()
    trace = Trace(
        robot_pos=robot_pos,
        robot_vel=np.diff(robot_pos, axis=0) / cfg.dt,
        robot_goal=np.asarray(world.robot_goal[env_index], dtype=float),
        robot_radius=float(cfg.robot_radius),
        human_pos=human_pos,
        human_goal=np.asarray(world.human_goal[env_index], dtype=float),
        human_radius=np.asarray(world.human_radius[env_index], dtype=float),
        scores=None,
        dt=float(cfg.dt),
    )
    fig, ax = _figure(5.0, 80, False)
    draw_trace(ax, trace)
    fig.canvas.draw()
    return _canvas_rgb(fig)
