"""Markdown tables generated from result folders (never typed by hand).

``crowdplan report DIR [DIR ...]`` finds every ``summary.json`` under the given folders and prints
one row per evaluation; training runs (folders with ``meta.json`` + ``validation.csv``) also get
their training time and last validation. ``crowdplan report --fill FILE.md`` writes these and the
other tables into a markdown page (:mod:`crowdplan.analysis.markdown_fill`).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from crowdplan.evaluation import format_interval, format_value

COLUMNS = [
    ("success_rate", "success", 3),
    ("collision_rate", "collision", 3),
    ("timeout_rate", "timeout", 3),
    ("time_to_goal", "time to goal (s)", 2),
    ("mean_distance", "mean dist (m)", 3),
    ("discomfort_frequency", "discomfort", 3),
    ("mean_reward", "mean reward", 3),
    ("path_length", "path (m)", 2),
]


def interval_cell(entry: dict | None, digits: int = 3) -> str:
    """Value and interval as the CLI prints them: "n/a" when missing, no interval without one."""
    if not entry:
        return "n/a"
    value = format_value(entry.get("value"), digits)
    return f"{value} {format_interval(entry.get('ci95'), digits)}".rstrip()


def _model_episode(summary_path: Path, meta: dict) -> str:
    """'K of T': the evaluated model was saved at training episode K of a run of T episodes
    (T read from the run's meta.json next to the result folder); '-' for planners."""
    if "episodes_trained" not in meta:
        return "-"
    selected = meta.get("selected_at_episode", meta["episodes_trained"])
    run_meta = summary_path.parent.parent / "meta.json"
    if not run_meta.exists():
        return str(selected)
    return f"{selected} of {json.loads(run_meta.read_text())['episodes']}"


def summary_table(paths: list[Path]) -> str:
    """One markdown row per summary.json: method, scenario, humans, cases, metrics with CIs."""
    header = ["result", "policy", "scenario", "N", "cases", "model at episode"] + [
        label for _, label, _ in COLUMNS
    ]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for path in paths:
        data = json.loads(path.read_text())
        meta = data.get("meta", {})
        world = meta.get("world", {})
        row = [
            str(path.parent),
            meta.get("policy", "?"),
            world.get("scenario", "?"),
            str(world.get("humans", "?")),
            str(data["episodes"]["value"]),
            _model_episode(path, meta),
        ] + [interval_cell(data[key], digits) for key, _, digits in COLUMNS]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


TRAINING_HEADER = [
    "run",
    "seed",
    "episodes",
    "env steps",
    "h / 10k episodes",
    "last val success",
    "last val reward",
    "best val reward",
    "min to val success >= 0.99",
    "lowest val success after the first >= 0.95 (episode)",
]
FIRST_SUCCESS = 0.99  # the validation success whose first arrival the training table times
STABLE_FROM = 0.95  # after the first validation at this success, the table gives the lowest one


def minutes_to_success(run: Path, meta: dict, validations: list[dict[str, str]]) -> float | None:
    """Wall-clock minutes from the start of a run (pretraining included) to the end of the
    episode of its first validation with success >= :data:`FIRST_SUCCESS`; None if it never got
    there (or the run folder has no ``episodes.csv``)."""
    first = next(
        (int(r["episode"]) for r in validations if float(r["success_rate"]) >= FIRST_SUCCESS),
        None,
    )
    episodes = run / "episodes.csv"
    if first is None or not episodes.is_file():
        return None
    with open(episodes) as f:
        seconds = next(
            (float(r["train_seconds"]) for r in csv.DictReader(f) if int(r["episode"]) >= first),
            None,
        )
    if seconds is None:
        return None
    return (float(meta.get("pretrain_seconds") or 0.0) + seconds) / 60.0


def lowest_success_after(validations: list[dict[str, str]]) -> tuple[float, int] | None:
    """The lowest validation success from the first validation with success >=
    :data:`STABLE_FROM` on (that one included), and the episode of that first validation; None
    if no validation got there."""
    successes = [(int(r["episode"]), float(r["success_rate"])) for r in validations]
    first = next((i for i, (_, success) in enumerate(successes) if success >= STABLE_FROM), None)
    if first is None:
        return None
    return min(success for _, success in successes[first:]), successes[first][0]


def read_run(run: Path) -> tuple[dict, list[dict[str, str]]]:
    """A training run folder's ``meta.json`` and the rows of its ``validation.csv``."""
    meta = json.loads((run / "meta.json").read_text())
    with open(run / "validation.csv") as f:
        return meta, list(csv.DictReader(f))


def training_rows(run_dirs: list[Path]) -> list[list[str]]:
    """One row of :data:`TRAINING_HEADER` per run folder."""
    rows = []
    for run in run_dirs:
        meta, validations = read_run(run)
        last = validations[-1] if validations else {}
        best = max((float(r["mean_reward"]) for r in validations), default=float("nan"))
        minutes = minutes_to_success(run, meta, validations)
        stability = lowest_success_after(validations)
        rows.append(
            [
                str(run),
                str(meta["seed"]),
                str(meta["episodes"]),
                str(meta["env_steps"]),
                f"{meta['hours_per_10k_episodes']:.2f}",
                f"{float(last.get('success_rate', 'nan')):.3f}",
                f"{float(last.get('mean_reward', 'nan')):.3f}",
                f"{best:.3f}",
                "never" if minutes is None else f"{minutes:.0f}",
                "never" if stability is None else f"{stability[0]:.2f} ({stability[1]})",
            ]
        )
    return rows


def training_table(run_dirs: list[Path]) -> str:
    """Training progress of run folders: episodes, hours per 10k episodes, last validation."""
    lines = ["| " + " | ".join(TRAINING_HEADER) + " |", "|" + "---|" * len(TRAINING_HEADER)]
    lines += ["| " + " | ".join(row) + " |" for row in training_rows(run_dirs)]
    return "\n".join(lines)


def report(folders: list[str]) -> str:
    """Both tables for everything found under ``folders``."""
    summaries, runs = [], []
    for folder in folders:
        root = Path(folder)
        if not root.exists():
            raise FileNotFoundError(f"result folder {root} does not exist")
        summaries += sorted(root.rglob("summary.json"))
        runs += sorted(
            p.parent for p in root.rglob("meta.json") if (p.parent / "validation.csv").exists()
        )
    if not summaries and not runs:
        raise FileNotFoundError(f"no summary.json or training run under {folders}")
    parts = []
    if summaries:
        parts += ["### Evaluations (95% intervals in brackets)", "", summary_table(summaries)]
    if runs:
        parts += ["", "### Training runs", "", training_table(runs)]
    return "\n".join(parts) + "\n"
