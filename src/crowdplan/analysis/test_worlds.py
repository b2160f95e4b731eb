"""The test worlds a planner is judged in beyond the paper's protocol (docs/generalization.md).

Each world is a set of ``crowdplan eval`` arguments over the 500 test cases; running a planner
in every world writes one result folder per world:

    python -m crowdplan.analysis.test_worlds --out results/generalization lsa-dsac orca straight

Names are shipped models, run folders or model files; ``orca`` and ``straight`` are the built-in
planners. ``NAME@shield=S`` runs a model with the safety shield's horizon set to S seconds (0:
off) instead of the model's own (``crowdplan eval --shield``); its folder keeps that name. A model
file named ``best_model.pt``, ``final_model.pt`` or ``model.pt`` writes to its folder's name. Every
world starts from the default (the paper's) world, whatever world a model was trained in
(``crowdplan eval --default-world``). Replayed pedestrians come from the held-out ETH/UCY scenes
only (zara1, zara2, univ).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from crowdplan.policies import BUILTIN_POLICIES

TEST_WORLDS: dict[str, tuple[str, list[str]]] = {
    "circle": ("the paper's 500 circle_crossing cases, 5 ORCA humans", []),
    "circle-rotated": (
        "the same cases, each scene rotated by an angle drawn from its seed",
        ["--option", "random_goal_direction=true"],
    ),
    "empty": ("no humans", ["--humans", "0"]),
    "circle-10": ("10 ORCA humans, circle radius 4 m", ["--humans", "10"]),
    "circle-20": (
        "20 ORCA humans, circle radius 5.5 m (the smallest half-metre step that places all cases)",
        ["--humans", "20", "--option", "circle_radius=5.5"],
    ),
    "square": ("square_crossing (the paper's transfer test)", ["--scenario", "square_crossing"]),
    "social-force": (
        "circle_crossing with social-force humans",
        ["--option", "social_force_fraction=1.0"],
    ),
    "replay-heldout": (
        "replayed pedestrians of the held-out scenes zara1, zara2 and univ (up to 10)",
        ["--scenario", "replay", "--humans", "10", "--option", "replay_scenes=[zara1,zara2,univ]"],
    ),
}


def split_planner(planner: str) -> tuple[str, str | None]:
    """``NAME[@shield=SECONDS]`` as ``(NAME, SECONDS or None)``; any other option is refused."""
    name, at, option = planner.partition("@")
    key, _, value = option.partition("=")
    if at and (key != "shield" or not value):
        raise ValueError(f"planner {planner!r}: the only option is NAME@shield=SECONDS")
    return name, value if at else None


def eval_arguments(planner: str, world: str, out: Path, episodes: int) -> list[str]:
    """``crowdplan eval`` arguments of one planner in one test world."""
    name, shield = split_planner(planner)
    source = ["--policy", name] if name in BUILTIN_POLICIES else ["--model", name]
    if shield is not None:
        source += ["--shield", shield]
    _, options = TEST_WORLDS[world]
    return [
        "eval",
        *source,
        *options,
        "--default-world",
        "--episodes",
        str(episodes),
        "--out",
        str(out),
        "--force",
        "--quiet",
    ]


MODEL_FILE_STEMS = ("best_model", "final_model", "model")  # named after their folder instead


def planner_label(planner: str) -> str:
    """The result folder name of a planner: its name, the run (or model) folder of a model file
    such as ``results/train/RUN/best_model.pt``, with its ``@shield=S`` option kept."""
    name, shield = split_planner(planner)
    path = Path(name)
    if path.suffix == ".pt" and path.stem in MODEL_FILE_STEMS and path.parent.name:
        path = path.parent
    return path.name + ("" if shield is None else f"@shield={shield}")


def main(argv: list[str] | None = None) -> int:
    from crowdplan.cli import main as crowdplan

    parser = argparse.ArgumentParser(description="Evaluate planners in every test world.")
    parser.add_argument("planners", nargs="+", help="shipped model names, model paths, orca")
    parser.add_argument("--out", required=True, help="results/<world>/<planner>/ are written here")
    parser.add_argument("--episodes", type=int, default=500, help="test cases per world (500)")
    parser.add_argument("--worlds", nargs="*", default=list(TEST_WORLDS), choices=list(TEST_WORLDS))
    args = parser.parse_args(argv)
    labels = [planner_label(planner) for planner in args.planners]
    for label in sorted(set(labels)):
        same = [p for p, other in zip(args.planners, labels, strict=True) if other == label]
        if len(same) > 1:
            parser.error(f"planners {same} would all write to <world>/{label}: name each once")
    for world in args.worlds:
        for planner, label in zip(args.planners, labels, strict=True):
            out = Path(args.out) / world / label
            status = crowdplan(eval_arguments(planner, world, out, args.episodes))
            if status != 0:
                return status
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
