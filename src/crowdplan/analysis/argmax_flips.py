"""How the greedy action moves between validations: argmax flips on a fixed set of states.

docs/training.md infers that a DSAC collapse starts with the greedy action flipping in many
states at once. This module measures it. A run trained with ``keep_validation_models`` keeps the
greedy policy of every validation in ``validation_models/``; all of them are asked for their
action in the same **probe states**: the observations along ORCA's paths through the first
validation cases of the run's world (ORCA, so that the states do not depend on any snapshot).
Per validation it reports:

- ``flipped``: the fraction of probe states whose greedy action differs from the previous
  validation's;
- ``changed_from_final``: ... from the last snapshot's (how far the policy still is from where
  it ends);
- ``p_greedy``: the median probability of the greedy action (a softmax over the policy's
  scores; for DSAC the policy itself);
- ``narrow``: the fraction of probe states whose two best actions are within a factor of 2 in
  probability (score gap below log 2): the states where a small change flips the argmax;
- ``stops``: the fraction of probe states whose greedy action is the stop (action 0). ORCA's
  robot is on its way to the goal in every probe state, so a policy that stops in many of them
  has a region of standing still beside its own paths (docs/training.md, section 9);
- ``stop_gap``: in the probe states where the stop is greedy, the median score gap between it
  and the runner-up (for DSAC in nats of the policy's log-probabilities): how firmly the policy
  stops there. DSAC's policy loss moves the runner-up's logit in proportion to its probability,
  about ``exp(-stop_gap)`` of the stop's.

::

    python -m crowdplan.analysis.argmax_flips runs/RUN [--cases 100] [--out DIR]
    python -m crowdplan.analysis.argmax_flips MODEL.pt MODEL.pt ...   # any models of one world
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
from pathlib import Path

import numpy as np

from crowdplan import evaluation
from crowdplan.algos.orca_planner import OrcaPlanner
from crowdplan.config import WorldConfig
from crowdplan.io import atomic_write
from crowdplan.models import GreedyPolicy, load_model_policy
from crowdplan.sim.actions import STOP
from crowdplan.sim.world import RUNNING, World

SNAPSHOTS = "validation_models"
COLUMNS = (
    "model",
    "episode",
    "success_rate",
    "flipped",
    "changed_from_final",
    "p_greedy",
    "narrow",
    "stops",
    "stop_gap",
)


def probe_states(world: WorldConfig, cases: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observations ``(robot, humans, mask)`` of every step of a holonomic ORCA robot in the
    first ``cases`` validation cases of ``world`` (finished episodes contribute no more)."""
    world = dataclasses.replace(world, kinematics="holonomic")
    sim = World(world, cases)
    sim.reset(evaluation.validation_seeds(cases))
    orca = OrcaPlanner(world.dt)
    active = np.ones(cases, dtype=bool)
    states: list[tuple[np.ndarray, ...]] = []
    while active.any():
        robot, humans, mask = sim.observe()
        states.append((robot[active], humans[active], mask[active]))
        result = sim.step(orca.act(robot, humans, mask).actions, active)
        active &= result.outcome == RUNNING
    return tuple(np.concatenate([s[i] for s in states]) for i in range(3))


def snapshots(folder: Path) -> list[Path]:
    """The validation snapshots of a run folder, in episode order."""
    paths = sorted((folder / SNAPSHOTS).glob("episode-*.pt"))
    if not paths:
        raise FileNotFoundError(
            f"{folder / SNAPSHOTS} holds no snapshots; train (or resume) the run with "
            "--keep-validation-models"
        )
    return paths


def flip_table(paths: list[Path], cases: int = 100) -> list[dict[str, float]]:
    """One row per model file, in the order given (a run's :func:`snapshots`, or any models of
    the same world); see the module docstring for the columns. The probe states come from the
    first model's world."""
    probes = None
    scores, episodes, success = [], [], []
    for path in paths:
        policy, world = load_model_policy(str(path), shield=0)
        if not isinstance(policy, GreedyPolicy):
            raise ValueError(f"{path} is not a policy over the 81 actions (DSAC, DQN, A2C)")
        if probes is None:
            probes = probe_states(world, cases)
        scores.append(policy.network_outputs(*probes)[0].cpu().numpy())  # logits for DSAC
        episodes.append(int(policy.metadata["episodes_trained"]))  # the model file's info
        success.append(float(policy.metadata.get("success_rate", math.nan)))
    greedy = [s.argmax(axis=1) for s in scores]
    rows = []
    for k, s in enumerate(scores):
        top2 = np.sort(s, axis=1)[:, -2:]
        gaps, stops = top2[:, 1] - top2[:, 0], greedy[k] == STOP
        probs = np.exp(s - s.max(axis=1, keepdims=True))
        probs /= probs.sum(axis=1, keepdims=True)
        rows.append(
            {
                "model": str(paths[k]),
                "episode": episodes[k],
                "success_rate": success[k],
                "flipped": float(np.mean(greedy[k] != greedy[k - 1])) if k else math.nan,
                "changed_from_final": float(np.mean(greedy[k] != greedy[-1])),
                "p_greedy": float(np.median(probs.max(axis=1))),
                "narrow": float(np.mean(gaps < math.log(2))),
                "stops": float(np.mean(stops)),
                "stop_gap": float(np.median(gaps[stops])) if stops.any() else math.nan,
                "probe_states": len(s),
            }
        )
    return rows


def format_table(rows: list[dict[str, float]]) -> str:
    """Markdown table of :func:`flip_table`'s rows."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|---|" + "---:|" * (len(COLUMNS) - 1)]
    for row in rows:
        cells = [row["model"], str(row["episode"])]
        cells += ["" if math.isnan(row[c]) else f"{row[c]:.3f}" for c in COLUMNS[2:]]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict[str, float]], title: str, path: Path) -> None:
    """Validation success and the flipped, narrow and stop fractions against the episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    episodes = [r["episode"] for r in rows]
    fig, ax = plt.subplots(figsize=(8, 3.5))
    styles = (("success_rate", "k-"), ("flipped", "r.-"), ("narrow", "b.--"), ("stops", "g.-"))
    for column, style in styles:
        ax.plot(episodes, [r[column] for r in rows], style, label=column)
    ax.set_xlabel("training episode")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(title)
    ax.legend(loc="center right")
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=100), mode="wb")
    plt.close(fig)


def _write_csv(file, rows: list[dict[str, float]]) -> None:
    writer = csv.DictWriter(file, fieldnames=[*COLUMNS, "probe_states"], lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m crowdplan.analysis.argmax_flips", description=__doc__.split("\n")[0]
    )
    parser.add_argument(
        "run",
        nargs="+",
        help="a run folder trained with --keep-validation-models, or model files (.pt) of one "
        "world, compared in the order given",
    )
    parser.add_argument(
        "--cases", type=int, default=100, help="validation cases of the probe states (default: 100)"
    )
    parser.add_argument("--out", help="folder for argmax_flips.csv and .png (default: none)")
    args = parser.parse_args(argv)
    if not 1 <= args.cases <= 100:
        parser.error(f"--cases must be in [1, 100] (the validation split), got {args.cases}")
    if len(args.run) == 1 and Path(args.run[0]).is_dir():
        folder = Path(args.run[0])
        paths, name = snapshots(folder), folder.name
    else:
        paths, name = [Path(p) for p in args.run], "models"
    rows = flip_table(paths, args.cases)
    print(
        f"{rows[0]['probe_states']} probe states: ORCA's paths through validation cases "
        f"0..{args.cases - 1}"
    )
    print(format_table(rows), end="")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write(out / f"{name}-argmax_flips.csv", lambda f: _write_csv(f, rows))
        plot(rows, name, out / f"{name}-argmax_flips.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
