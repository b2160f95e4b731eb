"""Does every seed of a preset reach the training targets? One row per seed, one across them.

The targets are those of a reliable DSAC preset (docs/training.md): on the run's 500-case test
(``RUN/test/summary.json``) a success rate of at least :data:`SUCCESS_TARGET` and a mean time to
goal of at most :data:`TIME_TARGET` seconds, and validations that never fall below
:data:`STABLE_FLOOR` once one has reached :data:`~crowdplan.analysis.report.STABLE_FROM`. The
table also gives the minutes to the first validation success of 0.99 (goal: a median of at most
:data:`MINUTES_TARGET`). The across-seed row is the mean with its Student-t 95% interval
(:func:`crowdplan.analysis.stats.across_seeds`) and how many seeds met each target.

``crowdplan report --seeds RUN [RUN ...]`` prints it; a ``<!-- crowdplan report --seeds ... -->``
block of a markdown page holds it.
"""

from __future__ import annotations

import json
import math
import statistics
from dataclasses import dataclass
from pathlib import Path

from crowdplan.analysis.report import lowest_success_after, minutes_to_success, read_run
from crowdplan.analysis.stats import across_seeds

SUCCESS_TARGET = 0.99
TIME_TARGET = 10.9  # seconds; the paper's LSA-DSAC: 10.94
STABLE_FLOOR = 0.9
MINUTES_TARGET = 20.0

HEADER = [
    "run",
    "seed",
    "episodes",
    f"test success (>= {SUCCESS_TARGET})",
    f"time to goal, s (<= {TIME_TARGET})",
    "first val success >= 0.95 at episode",
    f"lowest val success after it (>= {STABLE_FLOOR})",
    "min to val success >= 0.99",
    "targets met",
]


@dataclass(frozen=True)
class SeedResult:
    """What one training run reached, read from its folder."""

    run: Path
    seed: int
    episodes: int
    success: float | None  # None: the run has no test yet
    time_to_goal: float | None
    first_stable_episode: int | None
    lowest_after: float | None
    minutes: float | None

    @property
    def meets_success(self) -> bool:
        return self.success is not None and self.success >= SUCCESS_TARGET

    @property
    def meets_time(self) -> bool:
        return self.time_to_goal is not None and self.time_to_goal <= TIME_TARGET

    @property
    def stable(self) -> bool:
        return self.lowest_after is not None and self.lowest_after >= STABLE_FLOOR


def read_seed(run: str | Path) -> SeedResult:
    """A training run folder's test result, validation stability and time to 0.99."""
    run = Path(run)
    if not (run / "meta.json").is_file() or not (run / "validation.csv").is_file():
        raise FileNotFoundError(
            f"{run} is not a training run folder (meta.json and validation.csv); give the folders "
            "of `crowdplan train` or `make publish` (results/train/NAME)"
        )
    meta, validations = read_run(run)
    summary = run / "test" / "summary.json"
    success = time_to_goal = None
    if summary.is_file():
        data = json.loads(summary.read_text())
        success = data["success_rate"]["value"]
        time_to_goal = data["time_to_goal"]["value"]
    stability = lowest_success_after(validations)
    return SeedResult(
        run=run,
        seed=int(meta["seed"]),
        episodes=int(meta["episodes"]),
        success=success,
        time_to_goal=time_to_goal,
        first_stable_episode=None if stability is None else stability[1],
        lowest_after=None if stability is None else stability[0],
        minutes=minutes_to_success(run, meta, validations),
    )


def _value(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _met(result: SeedResult) -> str:
    names = [("success", result.meets_success), ("time", result.meets_time)]
    names.append(("stable", result.stable))
    met = [name for name, ok in names if ok]
    return ", ".join(met) if met else "none"


def seed_rows(results: list[SeedResult]) -> list[list[str]]:
    """One row of :data:`HEADER` per seed, then the across-seed row; runs that share a seed
    (one seed under different options) get no across row: their spread is not a seed's."""
    rows = [
        [
            str(r.run),
            str(r.seed),
            str(r.episodes),
            _value(r.success, 3),
            _value(r.time_to_goal, 2),
            "never" if r.first_stable_episode is None else str(r.first_stable_episode),
            _value(r.lowest_after, 2),
            "never" if r.minutes is None else f"{r.minutes:.0f}",
            _met(r),
        ]
        for r in results
    ]
    n = len(results)
    if len({r.seed for r in results}) < n:
        return rows
    # a seed that never got there counts as slower than any that did
    median = statistics.median(math.inf if r.minutes is None else r.minutes for r in results)
    success = across_seeds([r.success for r in results], bounds=(0.0, 1.0))
    time_to_goal = across_seeds([r.time_to_goal for r in results], bounds=(0.0, float("inf")))
    counts = (
        f"success {sum(r.meets_success for r in results)} of {n}, "
        f"time {sum(r.meets_time for r in results)} of {n}, "
        f"stable {sum(r.stable for r in results)} of {n}"
    )
    rows.append(
        [
            f"**across {n} seeds** (mean [95% interval]; minutes: median)",
            "-",
            "-",
            success.text(3) if success.values else "-",
            time_to_goal.text(2) if time_to_goal.values else "-",
            "-",
            "-",
            "never" if math.isinf(median) else f"{median:.0f}",
            counts,
        ]
    )
    return rows


def seed_table(runs: list[str | Path]) -> str:
    """The markdown table of :func:`seed_rows` for the given run folders."""
    if not runs:
        raise ValueError("--seeds needs the training run folders of one preset's seeds")
    rows = seed_rows([read_seed(run) for run in runs])
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"
