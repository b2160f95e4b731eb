"""Sweeps: a grid of settings x seeds, one resumable ``crowdplan train`` run folder per trial.

A sweep folder holds:
    sweep.json              the base config (resolved) and threads per trial; a re-run must match
    sweep.lock              while a sweep writes the folder (pid, host, start time)
    configs/<trial>.yaml    each trial's full config (trial = <setting>-s<seed>)
    runs/<trial>/           each trial's run folder (as `crowdplan train --out` makes it)
    logs/<trial>.log        each trial's output, appended over its attempts
    results/<trial>.json    written when a trial finished: its final metrics
    summary.json, summary.md   mean and 95% interval across seeds of each setting, and each
                            finished trial's metrics and training stability (summary.json also:
                            trials run by the last invocation and its wall-clock seconds)

Re-running the same command skips trials with a result, resumes those with a checkpoint and
starts the others afresh.
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import json
import math
import os
import re
import shutil
import socket
import time
from collections.abc import Callable, Iterator
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from crowdplan.analysis.stats import across_seeds
from crowdplan.backends import Backend, JobInterrupted
from crowdplan.command import EXIT_INTERRUPTED
from crowdplan.config_overrides import assign, parse_assignments
from crowdplan.evaluation import format_value
from crowdplan.io import atomic_write, write_json
from crowdplan.training.cli import main as train_main

# Metrics of a trial, from its test cases when the config tests, else its last validation.
TRIAL_METRICS = ("success_rate", "collision_rate", "timeout_rate", "time_to_goal", "mean_reward")
RATE, POSITIVE = (0.0, 1.0), (0.0, math.inf)
BOUNDS = {
    "success_rate": RATE,
    "collision_rate": RATE,
    "timeout_rate": RATE,
    "time_to_goal": POSITIVE,
    "hours_per_10k_episodes": POSITIVE,
}


@dataclass(frozen=True)
class Trial:
    """One run of the sweep: a setting (grid point) and a seed."""

    setting: str
    seed: int
    config: dict[str, Any]

    @property
    def name(self) -> str:
        return f"{self.setting}-s{self.seed}"


# ---------------------------------------------------------------------- the command line's grid
def parse_seeds(text: str) -> list[int]:
    """``"0-9"`` (inclusive), ``"3"`` or ``"0,2,5"`` -> sorted distinct seeds >= 0."""
    seeds: set[int] = set()
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if not match:
            raise ValueError(f"--seeds must look like 0-9, 3 or 0,2,5 (seeds >= 0), got {text!r}")
        low = int(match[1])
        high = int(match[2]) if match[2] is not None else low
        if high < low:
            raise ValueError(f"--seeds range {part.strip()!r} is empty: write it as {high}-{low}")
        seeds.update(range(low, high + 1))
    return sorted(seeds)


def parse_grid(assignments: list[str], base: dict[str, Any]) -> list[tuple[str, list[Any]]]:
    """``["dsac.lr=1e-4,3e-4", ...]`` -> ``[("dsac.lr", [0.0001, 0.0003]), ...]``.

    Keys are dotted paths into the config as ``config.yaml`` writes it; each must exist there.
    Values are YAML scalars or flow sequences (:mod:`crowdplan.config_overrides`).
    """
    grid = parse_assignments(assignments, base)
    if any(key == "seed" for key, _ in grid):
        raise ValueError("--set seed=...: give seeds with --seeds (e.g. --seeds 0-9)")
    return grid


def _label(value: Any) -> str:
    text = json.dumps(value, separators=(",", ":")) if not isinstance(value, str) else value
    return re.sub(r"[^A-Za-z0-9._+\-\[\],]", "_", text)


def expand(
    base: dict[str, Any], grid: list[tuple[str, list[Any]]], seeds: list[int], threads: int
) -> list[Trial]:
    """Every (setting, seed) trial, each config checked like a YAML file before any runs."""
    from crowdplan.training.config import config_from_dict

    trials = []
    for values in itertools.product(*(v for _, v in grid)):
        pairs = list(zip((k for k, _ in grid), values, strict=True))
        setting = ",".join(f"{key}={_label(value)}" for key, value in pairs) or base["name"]
        for seed in seeds:
            data = copy.deepcopy(base)
            for key, value in pairs:
                assign(data, key, value)
            data.update(seed=seed, torch_threads=threads)
            try:
                config = config_from_dict(data)
            except (ValueError, TypeError) as error:
                raise ValueError(f"setting {setting}: {error}") from error
            plain = json.loads(json.dumps(config.to_dict()))  # tuples as lists, as YAML reads them
            trials.append(Trial(setting, seed, plain))
    return trials


def _as_read_now(config: Any) -> Any:
    """A config saved by an earlier version as this one reads it: options added since then take
    their defaults, so that a sweep started before they existed still resumes."""
    from crowdplan.training.config import config_from_dict, with_legacy_defaults

    try:
        return json.loads(json.dumps(config_from_dict(with_legacy_defaults(config)).to_dict()))
    except (ValueError, TypeError):
        return config  # not a valid config: compared as it is, and found different


# ---------------------------------------------------------------------- the sweep folder
class SweepFolder:
    """Paths of a sweep folder and the checks that keep two sweeps from mixing in it."""

    def __init__(self, root: str | Path):
        self.root = Path(root)

    def config(self, trial: str) -> Path:
        return self.root / "configs" / f"{trial}.yaml"

    def run(self, trial: str) -> Path:
        return self.root / "runs" / trial

    def log(self, trial: str) -> Path:
        return self.root / "logs" / f"{trial}.log"

    def result(self, trial: str) -> Path:
        return self.root / "results" / f"{trial}.json"

    def prepare(self, base: dict[str, Any], threads: int, trials: list[Trial]) -> None:
        """Write sweep.json and the trial configs, refusing a folder of another sweep (or of
        something else) and trial configs that differ from what is already there."""
        spec = json.loads(json.dumps({"base": base, "threads_per_trial": threads}))
        marker = self.root / "sweep.json"
        if marker.is_file():
            saved = json.loads(marker.read_text())
            saved["base"] = _as_read_now(saved.get("base"))
            if saved != spec:
                changed = sorted(k for k in spec if saved.get(k) != spec[k])
                raise ValueError(
                    f"--out {self.root} holds a sweep of another config (differs in {changed}); "
                    "give another --out, or the same --config and --threads-per-trial"
                )
        elif self.root.is_dir() and any(p.name != "sweep.lock" for p in self.root.iterdir()):
            raise ValueError(
                f"--out {self.root} exists and is not a sweep folder (no sweep.json); give a new "
                "or empty folder so that nothing in it is overwritten"
            )
        for trial in trials:
            path = self.config(trial.name)
            if path.is_file() and _as_read_now(yaml.safe_load(path.read_text())) != trial.config:
                raise ValueError(f"{path} holds another config than trial {trial.name} has now")
        write_json(marker, spec)
        for trial in trials:
            atomic_write(
                self.config(trial.name),
                lambda f, t=trial: yaml.safe_dump(t.config, f, sort_keys=False),
            )

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold ``sweep.lock`` while the sweep runs; another live holder is an error. A lock left
        by a process of this host that no longer exists is taken over."""
        path = self.root / "sweep.lock"
        if self.root.exists() and not self.root.is_dir():
            raise ValueError(f"--out {self.root} is a file; give a folder for the sweep")
        self.root.mkdir(parents=True, exist_ok=True)
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time()}
        for _ in range(2):
            try:
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                holder = _read_lock(path)
                if holder and holder.get("host") == me["host"] and not _alive(holder.get("pid")):
                    path.unlink(missing_ok=True)  # its sweep died without cleaning up
                    continue
                since = time.strftime(
                    "%Y-%m-%d %H:%M:%S", time.localtime((holder or {}).get("started", 0))
                )
                raise ValueError(
                    f"{self.root} is being written by another sweep (pid "
                    f"{(holder or {}).get('pid')} on {(holder or {}).get('host')}, since {since}); "
                    f"wait for it, or delete {path} if that sweep is gone"
                ) from None
            with os.fdopen(fd, "w") as f:
                json.dump(me, f)
            break
        try:
            yield
        finally:
            path.unlink(missing_ok=True)


def _read_lock(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _alive(pid: Any) -> bool:
    if not isinstance(pid, int):
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# ---------------------------------------------------------------------- one trial (in a worker)
def run_trial(root: str, name: str) -> dict[str, Any]:
    """Run (or resume, or skip) trial ``name`` of the sweep in ``root``; returns its result.

    Raises JobInterrupted when a signal stopped it after writing its checkpoint; any other
    failure is returned as ``{"trial": name, "error": ...}`` so that the other trials go on.
    """
    folder = SweepFolder(root)
    result_path = folder.result(name)
    if result_path.is_file():
        return json.loads(result_path.read_text())
    run_dir = folder.run(name)
    if (run_dir / "checkpoint.pt").is_file():
        budget = yaml.safe_load(folder.config(name).read_text())["episodes"]
        meta = run_dir / "meta.json"
        if meta.is_file():  # the last batch of episodes may end past the budget: never shrink it
            budget = max(budget, json.loads(meta.read_text())["episodes"])
        argv = ["--out", str(run_dir), "--resume", "--episodes", str(budget)]
        argv.append("--no-progress")
    else:
        if run_dir.exists():
            shutil.rmtree(run_dir)  # started but stopped before its first checkpoint
        argv = ["--config", str(folder.config(name)), "--out", str(run_dir)]
        argv.append("--no-progress")
    log = folder.log(name)
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "a") as out, redirect_stdout(out), redirect_stderr(out):
        print(f"pid {os.getpid()} on {socket.gethostname()}: crowdplan train {' '.join(argv)}")
        out.flush()
        try:
            status = train_main(argv)
        except Exception as error:  # the other trials go on; the summary lists this one
            return {"trial": name, "error": f"{type(error).__name__}: {error}; see {log}"}
    if status == EXIT_INTERRUPTED:
        raise JobInterrupted(f"trial {name} was stopped; its checkpoint is in {run_dir}")
    if status != 0:
        return {"trial": name, "error": f"crowdplan train exited with status {status}; see {log}"}
    write_json(result_path, trial_result(name, run_dir))
    return json.loads(result_path.read_text())  # as a re-run reads it (nan as null)


def trial_result(name: str, run_dir: Path) -> dict[str, Any]:
    """A finished run folder's metrics: its test cases if it has them, else its last validation."""
    meta = json.loads((run_dir / "meta.json").read_text())
    test = run_dir / "test" / "summary.json"
    if test.is_file():
        summary = json.loads(test.read_text())
        metrics = {k: summary[k]["value"] for k in TRIAL_METRICS}
        config = yaml.safe_load((run_dir / "config.yaml").read_text())
        world = ", paper world" if config.get("test_world") == "paper" else ""
        source = f"test ({summary['episodes']['value']} cases{world})"
    else:
        import csv

        with open(run_dir / "validation.csv") as f:
            last = list(csv.DictReader(f))[-1]
        metrics = {k: float(last[k]) if last[k] != "" else math.nan for k in TRIAL_METRICS}
        source = f"last validation (episode {last['episode']})"
    return {
        "trial": name,
        "seed": meta["seed"],
        "episodes": meta["episodes"],
        "hours_per_10k_episodes": meta["hours_per_10k_episodes"],
        "source": source,
        **metrics,
        **training_stability(run_dir),
    }


def training_stability(run_dir: Path) -> dict[str, Any]:
    """From a run's validation log: minutes to the first validation success of 0.99, the episode
    of the first of 0.95 and the lowest validation success from there on (None where it never got
    there; ``crowdplan.analysis.report``, docs/training.md section 7)."""
    from crowdplan.analysis.report import lowest_success_after, minutes_to_success, read_run

    meta, validations = read_run(run_dir)
    lowest = lowest_success_after(validations)
    return {
        "minutes_to_val_success_0.99": minutes_to_success(run_dir, meta, validations),
        "first_val_success_0.95_episode": lowest[1] if lowest else None,
        "lowest_val_success_after_0.95": lowest[0] if lowest else None,
    }


# ---------------------------------------------------------------------- the sweep
def run_sweep(
    root: str | Path,
    base: dict[str, Any],
    trials: list[Trial],
    threads: int,
    open_backend: Callable[[], Backend],
    report: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run every trial on the backend that ``open_backend`` starts once the folder is locked and
    checked (finished trials are skipped, stopped ones resumed), then write and return the
    summary across seeds. Trials that failed are listed in it."""
    folder = SweepFolder(root)
    with folder.lock():
        folder.prepare(base, threads, trials)
        results = {
            t.name: json.loads(folder.result(t.name).read_text())
            for t in trials
            if folder.result(t.name).is_file()
        }
        todo = [t for t in trials if t.name not in results]
        resumed = sum((folder.run(t.name) / "checkpoint.pt").is_file() for t in todo)
        report(
            f"{len(trials)} trial(s): {len(results)} finished before, {resumed} to resume, "
            f"{len(todo) - resumed} to start"
        )
        jobs = [(str(folder.root), t.name) for t in todo]
        start = time.perf_counter()
        backend = open_backend() if jobs else None
        try:
            for index, result in backend.map(run_trial, jobs, threads) if backend else ():
                name = todo[index].name
                results[name] = result
                state = "failed: " + result["error"] if "error" in result else "done"
                report(f"[{len(results)}/{len(trials)}] {name} {state}")
        finally:
            if backend is not None:
                backend.close()
        summary = summarize(trials, results)
        # this invocation's throughput, backend start included (docs/scaling.md)
        summary["run"] = {"trials_run": len(jobs), "wall_seconds": time.perf_counter() - start}
        write_json(folder.root / "summary.json", summary)
        atomic_write(folder.root / "summary.md", lambda f: f.write(format_summary(summary)))
    return summary


def summarize(trials: list[Trial], results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Per setting: its seeds and, per metric, the mean over seeds with its Student-t 95% interval
    (``crowdplan.analysis.stats.across_seeds``; none for a single seed)."""
    settings: dict[str, list[Trial]] = {}
    for trial in trials:
        settings.setdefault(trial.setting, []).append(trial)
    rows = []
    for setting, members in settings.items():
        done = [r for t in members if (r := results.get(t.name)) and "error" not in r]
        row: dict[str, Any] = {
            "setting": setting,
            "seeds": [r["seed"] for r in done],
            "failed": [t.name for t in members if t.name not in {r["trial"] for r in done}],
        }
        for metric in (*TRIAL_METRICS, "hours_per_10k_episodes"):
            bounds = BOUNDS.get(metric, (-math.inf, math.inf))
            seeds = across_seeds([r[metric] for r in done], bounds)
            ci = list(seeds.ci95) if seeds.ci95 else None
            row[metric] = {"mean": seeds.mean, "ci95": ci, "n": len(seeds.values)}
        rows.append(row)
    return {"settings": rows, "trials": [results.get(t.name) for t in trials]}


def format_summary(summary: dict[str, Any]) -> str:
    """Markdown table: one row per setting, mean [95% interval] across seeds."""
    metrics = (*TRIAL_METRICS, "hours_per_10k_episodes")
    lines = [
        "| setting | seeds | " + " | ".join(metrics) + " |",
        "|---|---:|" + "---:|" * len(metrics),
    ]
    for row in summary["settings"]:
        cells = []
        for metric in metrics:
            entry = row[metric]
            cell = format_value(entry["mean"])
            if entry["ci95"]:
                cell += f" [{format_value(entry['ci95'][0])}, {format_value(entry['ci95'][1])}]"
            cells.append(cell)
        seeds = f"{len(row['seeds'])}" + (
            f" ({len(row['failed'])} failed)" if row["failed"] else ""
        )
        lines.append(f"| {row['setting']} | {seeds} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n\n" + format_trials(summary["trials"])


TRIAL_COLUMNS = (
    "episodes",
    "success_rate",
    "time_to_goal",
    "minutes_to_val_success_0.99",
    "first_val_success_0.95_episode",
    "lowest_val_success_after_0.95",
)


def format_trials(trials: list[dict[str, Any] | None]) -> str:
    """Markdown table: one row per finished trial (per seed), with its training stability."""
    lines = [
        "| trial | seed | " + " | ".join(TRIAL_COLUMNS) + " | from |",
        "|---|---:|" + "---:|" * len(TRIAL_COLUMNS) + "---|",
    ]
    for trial in trials:
        if trial is None or "error" in trial:
            continue
        cells = [_trial_cell(trial, column) for column in TRIAL_COLUMNS]
        lines.append(
            f"| {trial['trial']} | {trial['seed']} | "
            + " | ".join(cells)
            + f" | {trial['source']} |"
        )
    return "\n".join(lines) + "\n"


def _trial_cell(trial: dict[str, Any], column: str) -> str:
    if column not in trial:
        return "-"  # a result written by a version without this column
    value = trial[column]
    if value is None:
        return "never"
    if isinstance(value, int):
        return str(value)
    return f"{value:.0f}" if column.startswith("minutes") else format_value(value)
