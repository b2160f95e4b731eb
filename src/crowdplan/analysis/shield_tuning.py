"""Choose the safety shield's horizon on cases that no test world uses (docs/generalization.md).

    python -m crowdplan.analysis.shield_tuning lsa-dsac --horizons 0 1 1.5 2 2.5 3 \\
        --out results/shield_tuning/lsa-dsac.json

Every horizon (0: no shield) plays the model in tuning worlds over the seeds 100..999, which lie
between the default validation cases (0..99) and the test cases (1000..1499) and which training
never draws (it starts at 2000); a run that validates on more than 100 cases (``val_episodes``)
selects on some of them too: both are development cases, never test cases. The worlds are the
test worlds' settings except that replayed pedestrians come from the development scenes eth and
hotel: the held-out scenes (zara1, zara2, univ) are never used to choose anything. Writes one
JSON file of success, collision and timeout rates and the time to goal per world and horizon,
and prints them as a Markdown table.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from crowdplan.evaluation import Split, run_episodes, summarize
from crowdplan.io import write_json
from crowdplan.models import load_model_policy

TUNING = Split("tune", 100, 900)

TUNING_WORLDS: dict[str, dict] = {
    "circle": {},
    "circle-10": {"humans": 10},
    "circle-20": {"humans": 20, "circle_radius": 5.5},
    "square": {"scenario": "square_crossing"},
    "social-force": {"social_force_fraction": 1.0},
    "replay-dev": {"scenario": "replay", "humans": 10, "replay_scenes": ("eth", "hotel")},
}


def tune(
    model: str, horizons: list[float], worlds: list[str], cases: int = TUNING.cases
) -> dict[str, dict[str, dict]]:
    """``{world: {horizon: rates}}`` of ``model`` with each shield horizon (0: none), over the
    first ``cases`` tuning seeds."""
    table: dict[str, dict[str, dict]] = {}
    for world in worlds:
        table[world] = {}
        for horizon in horizons:
            policy, trained = load_model_policy(model, shield=horizon)
            config = trained.paper_world().replace(**TUNING_WORLDS[world])
            summary = summarize(run_episodes(policy, config, TUNING.seeds(cases)), config)
            table[world][str(horizon)] = {
                key: summary[key]["value"]
                for key in ("success_rate", "collision_rate", "timeout_rate", "time_to_goal")
            }
    return table


def markdown(table: dict[str, dict[str, dict]]) -> str:
    """Success (collision) rate per world (rows) and horizon (columns)."""
    horizons = list(next(iter(table.values())))
    lines = [
        "| world | " + " | ".join(f"{h} s" if float(h) else "no shield" for h in horizons) + " |",
        "|---|" + "---|" * len(horizons),
    ]
    for world, row in table.items():
        cells = [f"{r['success_rate']:.3f} ({r['collision_rate']:.3f})" for r in row.values()]
        lines.append(f"| {world} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", help="shipped model name, run folder or model file")
    parser.add_argument("--horizons", type=float, nargs="+", default=[0, 1, 1.5, 2, 2.5, 3])
    parser.add_argument("--worlds", nargs="+", default=list(TUNING_WORLDS), choices=TUNING_WORLDS)
    parser.add_argument("--cases", type=int, default=TUNING.cases, help="seeds 100.. (900)")
    parser.add_argument("--out", type=Path, help="JSON file to write (default: print only)")
    args = parser.parse_args(argv)
    table = tune(args.model, args.horizons, args.worlds, args.cases)
    last = TUNING.seed_base + args.cases - 1
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.out, {"model": args.model, "seeds": [100, last], "worlds": table})
    print(f"# {args.model}: success (collision) rate over seeds 100..{last}, by shield horizon")
    print(markdown(table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
