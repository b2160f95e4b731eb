"""How a planner ends the episodes it does not finish: the last seconds of every timeout.

A timeout is an episode that reached the time limit without reaching the goal or colliding. Its
last :data:`WINDOW` seconds of robot positions decide how it ended:

- ``frozen``: the robot travelled less than :data:`STILL` m in the window (it stood still);
- ``cycling``: it travelled at least :data:`CYCLE_PATH` m but ended within :data:`RETURN` m of
  where the window began (it moved back and forth in place);
- ``moving``: anything else (still on its way, or wandering).

Beside the split, each row gives the mean distance to the goal at the end, the share of timeouts
that ended farther from the goal than the robot started (outside every state of a training run
whose episodes all start at the same distance) and the share that ended with every human at
rest (speed under :data:`AT_REST`, e.g. arrived at their goals). With ``--probe-stop`` a last
column gives the share of frozen timeouts in which the planner still commands a stop when its
last state is changed to the robot moving at its preferred speed towards the goal: a robot that
stops for the scene, not a fixed point of its own zero velocity (which every planner observes)::

    python -m crowdplan.analysis.timeouts MODEL... [--scenario square_crossing] [--humans 5]
        [--probe-stop]

MODEL is anything ``crowdplan eval --model`` takes (a run folder, a model file, a shipped name);
the episodes are the test cases, replayed with traces.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch

from crowdplan.config import WorldConfig
from crowdplan.evaluation import TEST_CASES, EpisodeRecord, Trace, run_episodes, test_seeds
from crowdplan.models import load_model_policy
from crowdplan.policy import Policy
from crowdplan.sim.actions import STOP

WINDOW = 5.0  # s
STILL = 0.1  # m travelled in the window
CYCLE_PATH = 1.0  # m travelled in the window
RETURN = 0.5  # m from the window's first position
AT_REST = 0.05  # m/s
ENDINGS = ("frozen", "cycling", "moving")

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class Ending:
    """How one timeout ended."""

    kind: str  # one of ENDINGS
    goal_distance: float  # m, at the last state
    beyond_start: bool  # ended farther from the goal than it started
    crowd_at_rest: bool  # every present human slower than AT_REST at the last state


def ending(trace: Trace) -> Ending:
    """Classify the end of one episode's trace (see the module docstring)."""
    steps = max(1, round(WINDOW / trace.dt))
    window = trace.robot_pos[-(steps + 1) :]
    travelled = float(np.linalg.norm(np.diff(window, axis=0), axis=1).sum())
    net = float(np.linalg.norm(window[-1] - window[0]))
    if travelled < STILL:
        kind = "frozen"
    elif travelled >= CYCLE_PATH and net <= RETURN:
        kind = "cycling"
    else:
        kind = "moving"
    goal_distance = float(np.linalg.norm(trace.robot_goal - trace.robot_pos[-1]))
    start_distance = float(np.linalg.norm(trace.robot_goal - trace.robot_pos[0]))
    at_rest = True
    if trace.human_vel is not None and trace.human_vel.shape[1] > 0:
        speeds = np.linalg.norm(trace.human_vel[-1], axis=1)
        present = (
            np.ones(len(speeds), bool) if trace.human_present is None else trace.human_present[-1]
        )
        at_rest = bool((speeds[present] < AT_REST).all())
    return Ending(kind, goal_distance, goal_distance > start_distance, at_rest)


def last_state(
    trace: Trace, v_pref: float, moving: bool = False, holonomic: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The observation ``(robot (1, 9), humans (1, N, 5), present (1, N))`` of the trace's last
    state. The robot keeps its last velocity, or with ``moving`` goes at ``v_pref`` straight to
    its goal. Its heading: towards the goal when ``moving`` or for a unicycle (whose heading the
    trace does not keep), else the holonomic robot's fixed heading, start to goal, as the world
    keeps it."""
    if trace.human_vel is None:
        raise ValueError("the trace has no human velocities: run it with record_traces=True")
    position, goal = trace.robot_pos[-1], trace.robot_goal
    direction = (goal - position) / max(float(np.linalg.norm(goal - position)), 1e-9)
    velocity = v_pref * direction if moving else trace.robot_vel[-1]
    towards = direction if moving or not holonomic else goal - trace.robot_pos[0]
    heading = float(np.arctan2(towards[1], towards[0]))
    robot = np.array([*position, *velocity, trace.robot_radius, *goal, v_pref, heading])
    humans = np.concatenate(
        [trace.human_pos[-1], trace.human_vel[-1], trace.human_radius[:, None]], axis=1
    )
    present = np.ones(len(humans), bool) if trace.human_present is None else trace.human_present[-1]
    return robot[None], humans[None], present[None]


def stops_when_moving(policy: Policy, trace: Trace, v_pref: float) -> bool:
    """Whether ``policy`` commands a stop at the trace's last state with the robot's velocity
    replaced by ``v_pref`` towards its goal (a unicycle also heading there).

    A stop is the discrete table's :data:`~crowdplan.sim.actions.STOP` or a velocity command
    slower than 1e-6 m/s.
    """
    action = np.asarray(policy.act(*last_state(trace, v_pref, moving=True)).actions)[0]
    if action.ndim == 0:
        return int(action) == STOP
    return float(np.linalg.norm(action)) < 1e-6


def timeout_endings(records: list[EpisodeRecord]) -> list[Ending]:
    """The endings of the records that timed out (each must carry its trace)."""
    endings = []
    for record in records:
        if record.outcome != "timeout":
            continue
        if record.trace is None:
            raise ValueError(f"episode {record.seed} has no trace: run it with record_traces=True")
        endings.append(ending(record.trace))
    return endings


def frozen(records: list[EpisodeRecord]) -> list[Trace]:
    """The traces of the timeouts among ``records`` that ended frozen."""
    traces = [r.trace for r in records if r.outcome == "timeout"]  # each checked below
    return [t for t, e in zip(traces, timeout_endings(records), strict=True) if e.kind == "frozen"]


def summary_row(
    name: str, records: list[EpisodeRecord], stop_probe: list[bool] | None = None
) -> list[str]:
    """One table row: outcomes of the episodes and how their timeouts ended; with
    ``stop_probe`` (:func:`stops_when_moving` of each frozen timeout) a last column, its mean."""
    n = len(records)
    outcomes = Counter(r.outcome for r in records)
    endings = timeout_endings(records)
    kinds = Counter(e.kind for e in endings)
    row = [name, str(n), f"{outcomes['goal'] / n:.3f}", f"{outcomes['timeout'] / n:.3f}"]
    probe = [] if stop_probe is None else [f"{np.mean(stop_probe):.2f}" if stop_probe else "-"]
    if not endings:
        return row + ["-"] * (len(ENDINGS) + 3) + probe
    row += [f"{kinds[k] / len(endings):.2f}" for k in ENDINGS]
    row.append(f"{np.mean([e.goal_distance for e in endings]):.2f}")
    row.append(f"{np.mean([e.beyond_start for e in endings]):.2f}")
    row.append(f"{np.mean([e.crowd_at_rest for e in endings]):.2f}")
    return row + probe


HEADER = [
    "model",
    "episodes",
    "success",
    "timeout",
    *(f"timeouts {k}" for k in ENDINGS),
    "goal distance at the end (m)",
    "ended beyond its start distance",
    "crowd at rest at the end",
]


def add_test_case_args(parser: argparse.ArgumentParser, scenario: str) -> None:
    """``--scenario``, ``--humans`` and ``--episodes``: the test cases a replay plays."""
    parser.add_argument(
        "--scenario", default=scenario, choices=("circle_crossing", "square_crossing")
    )
    parser.add_argument("--humans", type=int, default=5, help="humans in the test world")
    parser.add_argument("--episodes", type=int, default=500, help="test cases 0..N-1")


def check_test_case_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse, through ``parser``, test-case arguments outside their ranges."""
    if not 1 <= args.episodes <= TEST_CASES:
        parser.error(f"--episodes must be in 1..{TEST_CASES}, got {args.episodes}")
    if args.humans < 0:
        parser.error(f"--humans must be >= 0, got {args.humans}")


def load_each(parser: argparse.ArgumentParser, load: Callable[[T], R], items: list[T]) -> list[R]:
    """Every item loaded before the first episode runs; a missing or foreign file ends the
    command through ``parser`` with the loader's message."""
    try:
        return [load(item) for item in items]
    except (FileNotFoundError, ValueError) as error:
        parser.error(str(error))


def print_table_head(args: argparse.Namespace, header: list[str]) -> None:
    """The line naming a replay's test cases, then its markdown table header."""
    print(f"{args.scenario}, {args.humans} humans, test cases 0..{args.episodes - 1}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="+", help="run folders, model files or shipped names")
    add_test_case_args(parser, scenario="square_crossing")
    parser.add_argument(
        "--probe-stop",
        action="store_true",
        help="add the share of frozen timeouts that still stop with the robot moving to its goal",
    )
    args = parser.parse_args(argv)
    check_test_case_args(parser, args)
    torch.set_num_threads(1)
    loaded = load_each(parser, load_model_policy, args.models)
    header = HEADER + (["frozen, stops also when moving to the goal"] if args.probe_stop else [])
    print_table_head(args, header)
    for model, (policy, world) in zip(args.models, loaded, strict=True):
        config: WorldConfig = dataclasses.replace(world, scenario=args.scenario, humans=args.humans)
        records = run_episodes(policy, config, test_seeds(args.episodes), record_traces=True)
        probe = None
        if args.probe_stop:
            probe = [stops_when_moving(policy, t, config.robot_v_pref) for t in frozen(records)]
        print("| " + " | ".join(summary_row(model, records, probe)) + " |", flush=True)


if __name__ == "__main__":
    main()
