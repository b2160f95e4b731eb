"""What ``policy_average: K`` would have validated, selected and tested in a finished run.

Training never sees the averaged policy (:mod:`crowdplan.training.policy_average`), so a run made
with ``keep_validation_models: true`` and ``policy_average: 1`` holds everything a run of the
same config and seed with ``policy_average: K`` would have done: the same training episodes,
and at every validation the policies whose weights it would have averaged. This replays those
validations and writes the run folder the averaging run would have written (validation.csv,
best_model.pt, meta.json and config.yaml; episodes.csv and updates.csv are copied), ready for
``make publish RUN=DIR`` (tested against a real ``policy_average`` run).

    python -m crowdplan.analysis.averaged_validation runs/<run> --average 4 --out runs/<run>-avg4

Validations before the first kept model (a run resumed with ``--keep-validation-models``) are
left out; the first K - 1 rows after it average fewer than K policies, and meta.json says so.
``--select-by success`` replays the best-model selection of ``select_by: success`` as well (with
``--average 1``: the run's own policies under that rule), and ``--no-val-paper-world`` /
``--val-paper-world`` the selection without / with the paper's world beside the run's own
(``val_paper_world``), and ``--val-episodes N`` the run validated on its first N validation
cases instead of the run's own count (seeds 0..N-1; more cases tell closer policies apart).
The kept models of a run with ``policy_average: K`` are already the averaged policies: such a
run is replayed with ``--average 1`` only (the folder written keeps ``policy_average: K``), which
validates nothing again where the run's validation.csv holds the columns the replay needs on the
same cases (seconds, not minutes per run).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

import yaml

from crowdplan.analysis.plots import plot_training_curves
from crowdplan.io import atomic_write, write_json
from crowdplan.models import load_payload
from crowdplan.training.checkpoint import torch_save_atomic
from crowdplan.training.config import TrainConfig, load_config
from crowdplan.training.loop import (
    improves,
    selection_score,
    validation_columns,
    validation_row,
)
from crowdplan.training.policy_average import average_payloads, payload_policy
from crowdplan.training.run_logs import write_csv


def validation_models(run: Path) -> list[tuple[int, Path]]:
    """``(episode, path)`` of the run's kept validation models, in training order."""
    folder = run / "validation_models"
    models = sorted((int(p.stem.split("-")[1]), p) for p in folder.glob("episode-*.pt"))
    if not models:
        raise ValueError(
            f"{folder} holds no validation models: train the run with "
            "keep_validation_models: true (crowdplan train --keep-validation-models)"
        )
    return models


def replay(
    run: Path, average: int, config: TrainConfig, same_cases: bool = True
) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """Validation rows of the averaged policies and the best model (by the config's
    ``select_by``, the first of equals, as the training loop keeps it).

    With ``average`` 1 each kept model is the policy the run validated, so where the run's
    validation.csv holds every column this validation writes, on the same cases (``same_cases``),
    its rows are taken as they are instead of validating again (the same numbers: validation is
    deterministic)."""
    own_rows = {int(row["episode"]): row for row in _read_csv(run / "validation.csv")}
    columns = validation_columns(config)
    complete = all(row.keys() >= set(columns) for row in own_rows.values())
    reuse = same_cases and average == 1 and complete
    recent: list[dict[str, Any]] = []
    rows, best, best_score = [], None, None
    for episode, path in validation_models(run):
        payload = load_payload(path)
        payload["info"] = {k: v for k, v in payload["info"].items() if k != "success_rate"}
        recent = [*recent, payload][-average:]
        averaged = average_payloads(recent)
        own = own_rows[episode]
        if reuse:
            row = {"episode": episode, "env_steps": int(own["env_steps"])}
            row |= {key: float(own[key]) for key in columns}
        else:
            policy = payload_policy(averaged, config.name)
            row = validation_row(policy, config, episode, int(own["env_steps"]))
        rows.append(row)
        score = selection_score(row, config.select_by)
        if improves(score, best_score):
            best_score = score
            best = {**averaged, "info": {**averaged["info"], "selected_at_episode": episode}}
    return rows, best


def write_averaged_run(
    run: Path,
    average: int,
    out: Path,
    select_by: str | None = None,
    val_paper_world: bool | None = None,
    val_episodes: int | None = None,
) -> list[dict[str, Any]]:
    """The run folder ``policy_average: average`` (and ``select_by``, ``val_paper_world`` and
    ``val_episodes``, where given) would have made, in ``out`` (new or empty)."""
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} is not empty; give a new folder so that nothing is overwritten")
    saved = load_config(run / "config.yaml", legacy_defaults=True)
    if saved.policy_average > 1 and average != 1:
        raise ValueError(
            f"{run} trained with policy_average: {saved.policy_average}, so its kept models "
            "are already averaged policies: replay them with --average 1"
        )
    config = dataclasses.replace(
        saved,
        policy_average=saved.policy_average if saved.policy_average > 1 else average,
        keep_validation_models=False,
        select_by=select_by or saved.select_by,
        val_paper_world=saved.val_paper_world if val_paper_world is None else val_paper_world,
        val_episodes=val_episodes or saved.val_episodes,
    )
    rows, best = replay(run, average, config, config.val_episodes == saved.val_episodes)
    out.mkdir(parents=True, exist_ok=True)
    for name in ("episodes.csv", "updates.csv"):
        if (run / name).is_file():  # updates.csv is written from the first logged update on
            shutil.copy2(run / name, out / name)
    write_csv(out / "validation.csv", rows)
    atomic_write(
        out / "config.yaml", lambda f: yaml.safe_dump(config.to_dict(), f, sort_keys=False)
    )
    torch_save_atomic(out / "best_model.pt", best)
    meta = json.loads((run / "meta.json").read_text())
    meta["averaged_validation"] = {
        "from_run": str(run),
        "policy_average": config.policy_average,
        "select_by": config.select_by,
        "val_paper_world": config.val_paper_world,
        "val_episodes": config.val_episodes,
        "validations_left_out": [
            int(r["episode"])
            for r in _read_csv(run / "validation.csv")
            if int(r["episode"]) < rows[0]["episode"]
        ],
        "command": f"python -m crowdplan.analysis.averaged_validation {run} "
        f"--average {average}"
        + (f" --select-by {select_by}" if select_by is not None else "")
        + {None: "", True: " --val-paper-world", False: " --no-val-paper-world"}[val_paper_world]
        + (f" --val-episodes {val_episodes}" if val_episodes is not None else "")
        + f" --out {out}",
    }
    write_json(out / "meta.json", meta)
    plot_training_curves(out)
    return rows


def _read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m crowdplan.analysis.averaged_validation", description=__doc__.split("\n")[0]
    )
    parser.add_argument("run", type=Path, help="run folder with validation_models/")
    parser.add_argument(
        "--average", type=int, required=True, help="policies averaged (policy_average)"
    )
    parser.add_argument(
        "--select-by",
        choices=("reward", "success"),
        help="best-model selection to replay (default: the run's select_by)",
    )
    parser.add_argument(
        "--val-paper-world",
        action=argparse.BooleanOptionalAction,
        help="validate (and select) in the paper's world too, or not (default: as the run did)",
    )
    parser.add_argument(
        "--val-episodes",
        type=int,
        help="validation cases per validation, 1..1000 (default: as the run did)",
    )
    parser.add_argument("--out", type=Path, required=True, help="new run folder to write")
    args = parser.parse_args(argv)
    changed = (args.select_by, args.val_paper_world, args.val_episodes)
    lowest = 1 if any(option is not None for option in changed) else 2
    if args.average < lowest:
        parser.error(
            f"--average must be >= 2, or >= 1 with --select-by, --[no-]val-paper-world or "
            f"--val-episodes (1 alone is the run itself), got {args.average}"
        )
    live = {int(r["episode"]): r for r in _read_csv(args.run / "validation.csv")}
    try:
        rows = write_averaged_run(
            args.run,
            args.average,
            args.out,
            args.select_by,
            args.val_paper_world,
            args.val_episodes,
        )
    except ValueError as error:  # a bad option or folder: say what, not where in the code
        parser.error(str(error))
    print("| episode | success, run | success, replayed | reward, run | reward, replayed |")
    print("|---:|---:|---:|---:|---:|")
    for row in rows:
        own = live[row["episode"]]
        print(
            f"| {row['episode']} | {float(own['success_rate']):.2f} | {row['success_rate']:.2f} "
            f"| {float(own['mean_reward']):.3f} | {row['mean_reward']:.3f} |"
        )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
