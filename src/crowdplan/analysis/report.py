"""Markdown tables generated from result folders (never typed by hand).

``crowdplan report DIR [DIR ...]`` finds every ``summary.json`` under the given folders and prints
one row per evaluation; training runs (folders with ``meta.json`` + ``validation.csv``) also get
their training time and last validation.

``crowdplan report --fill FILE.md`` regenerates every block of a markdown page that sits between
``<!-- crowdplan report DIR [DIR ...] -->`` and ``<!-- end report -->`` from those folders, so that
the tables of docs/results.md are always the output of the command written above them. A block
``<!-- crowdplan report --transfer DIR -->`` holds the planner x test-world table of a folder
written by ``python -m crowdplan.analysis.test_worlds`` and its paired comparisons. A block
``<!-- crowdplan report --paper METHOD=DIR ... -->`` holds the paper's comparison tables
(:mod:`crowdplan.analysis.paper_tables`), one ``<!-- crowdplan report --seeds RUN ... -->`` the
seed targets of one preset's runs (:mod:`crowdplan.analysis.seed_targets`).
"""

from __future__ import annotations

import csv
import json
import re
import shlex
from pathlib import Path

from crowdplan.evaluation import format_interval, format_value
from crowdplan.io import atomic_write

_BLOCK = re.compile(
    r"(?P<head><!-- crowdplan report (?P<args>[^>]*?) -->\n).*?(?P<end><!-- end report -->)", re.S
)

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


def _cell(entry: dict, digits: int) -> str:
    """Value and interval as the CLI prints them: "n/a" when missing, no interval without one."""
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
        ] + [_cell(data[key], digits) for key, _, digits in COLUMNS]
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


def fill_markdown(path: str | Path) -> int:
    """Regenerate the report blocks of a markdown file in place; returns how many were filled."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"markdown file {path} does not exist")
    text = path.read_text()
    count = 0

    def regenerate(match: re.Match) -> str:
        nonlocal count
        count += 1
        args = shlex.split(match["args"])
        if args[:1] == ["--transfer"]:
            from crowdplan.analysis.html_report import transfer_tables

            if len(args) != 2 or not Path(args[1]).is_dir():
                raise ValueError(f"{path}: a --transfer block names one existing folder: {args}")
            body = "\n".join(t.markdown() for t in transfer_tables(Path(args[1])))
        elif args[:1] == ["--seeds"]:
            from crowdplan.analysis.seed_targets import seed_table

            body = seed_table(args[1:]).rstrip("\n")
        elif args[:1] == ["--paper"]:
            from crowdplan.analysis.paper_tables import paper_report

            body = paper_report(args[1:])
        else:
            body = report(args)
        return f"{match['head']}\n{body}\n{match['end']}"

    new_text = _BLOCK.sub(regenerate, text)
    if count == 0:
        raise ValueError(
            f"{path} has no '<!-- crowdplan report DIR ... -->' ... '<!-- end report -->' block"
        )
    atomic_write(path, lambda f: f.write(new_text))
    return count
