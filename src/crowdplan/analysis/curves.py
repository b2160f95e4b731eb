"""Training curves of many runs, grouped into panels: the paper's figure 6, and the same
panels for the combined recipe (``configs/*_dsac_aln_avg.yaml``).

Run folders (``results/train/<run>/`` with config.yaml and episodes.csv) are found by
``discover_runs``; a run's *method* is its config name plus the crowd size (``-h<N>``), its seeds
are the runs of that method. Each panel draws the discounted return per training episode,
smoothed by a rolling mean, as the mean over seeds with the band between the lowest and highest
seed where at least two seeds reached that episode.
"""

from __future__ import annotations

import io
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from crowdplan.analysis.plots import _read, rolling_mean

SMOOTHING = 200  # episodes in the rolling mean
PAPER_ENCODERS = ("rg", "sa", "aw", "raw", "lsa")


@dataclass(frozen=True)
class Run:
    """A training run folder and what the panels group it by."""

    folder: Path
    name: str  # the config's name, e.g. lsa_dsac_ent05
    seed: int
    algo: str
    encoder: str
    humans: int
    rg_pooling: str
    share_encoder: bool

    @property
    def method(self) -> str:
        """The variant the run is a seed of: its folder's name without the ``-s<seed>`` suffix
        (``make publish`` names a sweep's variant there, e.g. ``lsa_dsac_aln_avgq-s4``, whose
        config keeps the preset's name), else the config's name and crowd size."""
        variant = re.fullmatch(rf"(.+)-s{self.seed}", self.folder.name)
        if variant:
            return variant.group(1)
        return self.name if self.humans == 5 else f"{self.name}-h{self.humans}"


def discover_runs(root: str | Path) -> list[Run]:
    """Every run folder under ``root`` with config.yaml and a non-empty episodes.csv."""
    runs = []
    for config_path in sorted(Path(root).glob("*/config.yaml")):
        folder = config_path.parent
        if not (folder / "episodes.csv").is_file():
            continue
        config = yaml.safe_load(config_path.read_text()) or {}
        encoder = config.get("encoder") or {}
        runs.append(
            Run(
                folder=folder,
                name=str(config.get("name", folder.name)),
                seed=int(config.get("seed", 0)),
                algo=str(config.get("algo", "dsac")),
                encoder=str(encoder.get("name", "")),
                humans=int((config.get("world") or {}).get("humans", 5)),
                rg_pooling=str(encoder.get("rg_pooling", "")),
                share_encoder=bool((config.get("dsac") or {}).get("share_encoder", False)),
            )
        )
    return runs


@dataclass(frozen=True)
class Panel:
    """One panel of the figure: a title and which runs belong, grouped into labelled lines."""

    key: str
    title: str
    select: Callable[[Run], bool]
    label: Callable[[Run], str]
    min_lines: int = 1  # an ablation panel needs something to contrast
    keep_lines: Callable[[dict[str, list[Run]]], dict[str, list[Run]]] | None = None


def _both_kinds(lines: dict[str, list[Run]]) -> dict[str, list[Run]]:
    """Keep the encoders that have both a shared and a separate line."""
    encoders = {label.split()[0] for label in lines}
    keep = {e for e in encoders if f"{e} shared" in lines and f"{e} separate" in lines}
    return {label: runs for label, runs in lines.items() if label.split()[0] in keep}


def _seeds_of(method: str) -> Callable[[Run], bool]:
    """Whether a DSAC run is a seed of a variant whose name (``Run.method``) fully matches the
    regular expression ``method``."""

    def select(run: Run) -> bool:
        return run.algo == "dsac" and re.fullmatch(method, run.method) is not None

    return select


def _encoder_preset(suffix: str, humans: int) -> Callable[[Run], bool]:
    """Seeds of the per-encoder preset ``<encoder>_dsac_<suffix>`` with ``humans`` humans."""
    return _seeds_of(rf"[a-z]+_dsac_{suffix}" + ("" if humans == 5 else f"-h{humans}"))


def _lsa_crowd_sizes(preset: str) -> Callable[[Run], bool]:
    """Seeds of the LSA-DSAC preset ``preset`` with 5 humans or its -h1 to -h4 and -h10 sizes."""
    return _seeds_of(rf"{preset}(-h([1-4]|10))?")


PANELS = (
    Panel(
        "a",
        "encoders, 5 humans, 0.5 log 81",
        _encoder_preset("ent05", humans=5),
        lambda r: r.encoder.upper(),
    ),
    Panel(
        "b",
        "encoders, 10 humans, 0.5 log 81",
        _encoder_preset("ent05", humans=10),
        lambda r: r.encoder.upper(),
    ),
    Panel(
        "c",
        "LSA-DSAC with 1-5 and 10 humans, 0.5 log 81",
        _lsa_crowd_sizes("lsa_dsac_ent05"),
        lambda r: f"{r.humans} human{'s' * (r.humans > 1)}",
    ),
    Panel(
        "d",
        "RG-DSAC pooling ablations",
        lambda r: r.algo == "dsac" and r.encoder == "rg" and r.humans == 5,
        lambda r: r.rg_pooling or r.name,
        min_lines=2,
    ),
    Panel(
        "e",
        "shared vs separate encoders",
        lambda r: r.algo == "dsac" and r.humans == 5 and r.encoder in PAPER_ENCODERS,
        lambda r: f"{r.encoder.upper()} {'shared' if r.share_encoder else 'separate'}",
        min_lines=2,
        keep_lines=_both_kinds,
    ),
    Panel(
        "f",
        "LSA-DSAC variants, 5 humans",
        lambda r: r.algo == "dsac" and r.encoder == "lsa" and r.humans == 5,
        lambda r: r.method,
    ),
    Panel(
        "g",
        "baselines (value-based and actor-critic)",
        lambda r: r.algo != "dsac",
        lambda r: r.method,
    ),
    Panel(
        "h",
        "encoders, 5 humans, combined recipe",
        _encoder_preset("aln_avg", humans=5),
        lambda r: r.encoder.upper(),
    ),
    Panel(
        "i",
        "LSA-DSAC with 1-5 and 10 humans, combined recipe",
        _lsa_crowd_sizes("lsa_dsac_aln_avg"),
        lambda r: f"{r.humans} human{'s' * (r.humans > 1)}",
    ),
    Panel(
        "j",
        "encoders, 10 humans, combined recipe",
        _encoder_preset("aln_avg", humans=10),
        lambda r: r.encoder.upper(),
    ),
)


def _smoothed(run: Run) -> tuple[np.ndarray, np.ndarray]:
    data = _read(run.folder / "episodes.csv")
    return data["episode"], rolling_mean(data["discounted_return"], SMOOTHING)


def panel_lines(panel: Panel, runs: list[Run]) -> dict[str, list[Run]]:
    """The runs of a panel by line label, filtered by its ``keep_lines`` (shared-vs-separate:
    only encoders trained both ways); empty when fewer than its ``min_lines`` are left."""
    lines: dict[str, list[Run]] = {}
    for run in runs:
        if panel.select(run):
            lines.setdefault(panel.label(run), []).append(run)
    if panel.keep_lines is not None:
        lines = panel.keep_lines(lines)
    if len(lines) < panel.min_lines:
        return {}
    return {label: lines[label] for label in sorted(lines, key=_natural_order)}


def _natural_order(label: str) -> list[str | int]:
    """Sort key that puts "2 humans" before "10 humans"."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", label)]


def seed_band(runs: list[Run]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Episodes, mean over seeds, and lowest/highest seed (nan where fewer than two seeds)."""
    curves = [_smoothed(r) for r in runs]
    last = int(max(x[-1] for x, _ in curves))
    grid = np.arange(1, last + 1, max(1, last // 400))
    stack = np.full((len(curves), grid.size), np.nan)
    for i, (x, y) in enumerate(curves):
        inside = grid <= x[-1]
        stack[i, inside] = np.interp(grid[inside], x, y)
    count = np.isfinite(stack).sum(axis=0)
    with np.errstate(all="ignore"):
        mean = np.nanmean(stack, axis=0)
        lo = np.where(count >= 2, np.nanmin(stack, axis=0), np.nan)
        hi = np.where(count >= 2, np.nanmax(stack, axis=0), np.nan)
    return grid, mean, lo, hi


def draw_panels(runs: list[Run]) -> tuple[bytes, list[tuple[Panel, dict[str, list[Run]]]]]:
    """PNG of every panel that has runs, and the runs drawn in each."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    drawn = [(p, lines) for p in PANELS if (lines := panel_lines(p, runs))]
    cols = 2
    rows = max(1, -(-len(drawn) // cols))
    fig = Figure(figsize=(11, 3.4 * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, (panel, lines) in zip(axes, drawn, strict=False):
        for label, members in lines.items():
            x, mean, lo, hi = seed_band(members)
            seeds = len(members)
            (line,) = ax.plot(x, mean, lw=1.3, label=f"{label} ({seeds} seed{'s' * (seeds > 1)})")
            if seeds > 1:
                ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        ax.set_title(f"({panel.key}) {panel.title}", fontsize=10)
        ax.set(xlabel="training episode", ylabel=f"discounted return (mean of {SMOOTHING})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    for ax in axes[len(drawn) :]:
        ax.set_axis_off()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    return buffer.getvalue(), drawn
