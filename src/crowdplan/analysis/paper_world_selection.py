"""Best-model selection by success in the paper's world, on many validation cases.

For each finished run made with ``keep_validation_models: true``, every kept validation policy
plays the first N validation cases (seeds 0..N-1, never test cases) in the paper's world with the
run's robot (:meth:`crowdplan.config.WorldConfig.paper_world`, the world of ``test_world: paper``
and of ``--default-world``). Among the policies whose success in the run's own validation
(validation.csv) is at least ``--min-own-success`` (0.95: the stability target's level; all
policies where none is), the one with the highest success rate in the paper's world is selected
(then the highest mean reward there; the first of equals). Without that floor a run of a preset
fine-tuned from the paper's model would select its first policies, still the paper's model and
not yet fit for the run's own world. With ``--test`` the selected policy plays the 500 test cases
of the paper's world, the network alone, as ``make publish RUN=... EVAL_ARGS=--default-world``
tests a run's own best model.

    python -m crowdplan.analysis.paper_world_selection runs/<run> ... --val-episodes 1000 \
        --test --out runs/<name>

Writes, per run, ``OUT/<run>/kept.csv`` (one row per kept policy: its success in the run's own
validation and its metrics on the paper world's validation cases), ``OUT/<run>/best_model.pt``
(the selected policy, for ``crowdplan eval`` and ``crowdplan.analysis.test_worlds``) and, with
``--test``, ``OUT/<run>/test/summary.json``; and ``OUT/summary.md``, a table over the runs. The
kept policies of a run trained with ``policy_average: K`` are the averaged policies it
validated, so they are selected as they are.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

import torch

from crowdplan import evaluation
from crowdplan.analysis.averaged_validation import validation_models
from crowdplan.io import atomic_write
from crowdplan.models import load_payload
from crowdplan.training.config import load_config
from crowdplan.training.policy_average import payload_policy
from crowdplan.training.run_logs import write_csv

METRICS = ("success_rate", "collision_rate", "time_to_goal", "mean_reward")
TARGET = 0.99  # the seed target on the paper's circle (docs/training.md section 9)


def kept_policy_rows(
    run: Path, models: list[tuple[int, Path]], val_episodes: int
) -> list[dict[str, Any]]:
    """One row per kept validation policy of ``run`` (``models``: its ``(episode, path)``
    pairs): its metrics on the first ``val_episodes`` validation cases in the paper's world."""
    config = load_config(run / "config.yaml")
    world = config.world.paper_world()
    seeds = evaluation.validation_seeds(val_episodes)
    with open(run / "validation.csv", newline="") as f:
        own = {int(row["episode"]): float(row["success_rate"]) for row in csv.DictReader(f)}
    rows = []
    for episode, path in models:
        policy = payload_policy(load_payload(path), config.name)
        summary = evaluation.summarize(evaluation.run_episodes(policy, world, seeds), world)
        row = {"episode": episode, "own_success_rate": own[episode]}
        rows.append(row | {k: summary[k]["value"] for k in METRICS})
    return rows


def select(rows: list[dict[str, Any]], min_own_success: float) -> dict[str, Any]:
    """Among the rows at ``min_own_success`` or above in the run's own validation (all rows
    where none is), the highest success rate, then the highest mean reward; the first of
    equals."""
    eligible = [row for row in rows if row["own_success_rate"] >= min_own_success] or rows
    return max(eligible, key=lambda row: (row["success_rate"], row["mean_reward"]))


def evaluate_on_test(run: Path, path: Path, out: Path) -> dict[str, Any]:
    """The policy of model file ``path`` on the 500 test cases of the paper's world, with
    ``run``'s robot; writes ``out``."""
    config = load_config(run / "config.yaml")
    policy = payload_policy(load_payload(path), config.name)
    world = config.world.paper_world()
    records = evaluation.run_episodes(policy, world, evaluation.test_seeds())
    summary = evaluation.summarize(records, world)
    meta = {"model": str(path), "split": "test"}
    evaluation.write_results(out, summary, records, meta)
    return summary


def _summary_line(
    run: Path, rows: list[dict[str, Any]], chosen: dict[str, Any], test: dict | None
) -> str:
    reaching = sum(row["success_rate"] >= TARGET for row in rows)
    cells = [
        run.name,
        str(len(rows)),
        str(reaching),
        f"{chosen['episode']}",
        f"{chosen['success_rate']:.3f}",
    ]
    if test is not None:
        cells += [
            evaluation.format_value(test["success_rate"]["value"]),
            evaluation.format_value(test["time_to_goal"]["value"], 2),
        ]
    return "| " + " | ".join(cells) + " |"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m crowdplan.analysis.paper_world_selection",
        description=__doc__.splitlines()[0],
    )
    parser.add_argument("runs", nargs="+", type=Path, help="run folders with validation_models/")
    parser.add_argument(
        "--val-episodes",
        type=int,
        default=evaluation.VAL_CASES,
        help=f"validation cases per policy, 1..{evaluation.VAL_CASES} (default: all)",
    )
    parser.add_argument(
        "--min-own-success",
        type=float,
        default=0.95,
        help="success in the run's own validation a policy needs to be selected (default 0.95)",
    )
    parser.add_argument("--test", action="store_true", help="test each run's selected policy")
    parser.add_argument("--out", type=Path, required=True, help="new folder to write")
    args = parser.parse_args(argv)
    if not 1 <= args.val_episodes <= evaluation.VAL_CASES:
        parser.error(f"--val-episodes must be 1..{evaluation.VAL_CASES}, got {args.val_episodes}")
    if not 0.0 <= args.min_own_success <= 1.0:
        parser.error(f"--min-own-success is a success rate in 0..1, got {args.min_own_success}")
    if args.out.exists() and any(args.out.iterdir()):
        parser.error(f"--out {args.out} is not empty: give a new folder")
    for run in args.runs:
        if not (run / "validation_models").is_dir():
            parser.error(
                f"{run} has no validation_models/: train it with keep_validation_models: true"
            )
    columns = ["run", "kept policies", f"at >= {TARGET} on the validation cases"]
    columns += ["selected episode", "its validation success"]
    if args.test:
        columns += ["test success", "time to goal (s)"]
    lines = [
        f"Paper's world, first {args.val_episodes} validation cases per kept policy; selected "
        f"among the policies at {args.min_own_success} or above in their run's own validation.",
        "",
        "| " + " | ".join(columns) + " |",
        "|" + "---|" * len(columns),
    ]
    torch.set_num_threads(1)  # small networks: one thread each, as every crowdplan command
    for run in args.runs:
        models = validation_models(run)
        rows = kept_policy_rows(run, models, args.val_episodes)
        write_csv(args.out / run.name / "kept.csv", rows)
        chosen = select(rows, args.min_own_success)
        model = args.out / run.name / "best_model.pt"
        chosen_bytes = dict(models)[chosen["episode"]].read_bytes()
        atomic_write(model, lambda f, data=chosen_bytes: f.write(data), mode="wb")
        test = evaluate_on_test(run, model, args.out / run.name / "test") if args.test else None
        lines.append(_summary_line(run, rows, chosen, test))
        print(lines[-1], flush=True)
    atomic_write(args.out / "summary.md", lambda f: f.write("\n".join(lines) + "\n"))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
