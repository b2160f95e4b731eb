"""Strategy of a trajectory (the paper's tables IV and V), decided by the rules of
docs/strategies.md from a recorded trace.

The rules look at each step from the state the robot decided in (states 0..T-1), with the
robot's velocity of that step and the humans' velocities during it. They are applied in order;
the first that holds names the strategy:

1. cross: the episode ended in a collision, or the robot cut between two humans (both within
   ``CUT_GAP`` of its edge, on opposite sides of its direction of motion, while it moved).
2. back-pass: it retreated: its progress along the start-goal axis fell at least ``BACK_DIST``
   below the furthest it had reached.
3. wait-pass: it was slower than ``WAIT_SPEED`` while blocked (a human within ``BLOCK_GAP`` of
   its edge, towards its goal) for at least ``WAIT_TIME`` seconds in total.
4. follow-pass: it moved behind a human walking its way (ahead within ``FOLLOW_ANGLE`` of its
   direction of motion, within ``FOLLOW_GAP``, velocities within ``FOLLOW_HEADING``) for at
   least ``FOLLOW_TIME`` seconds in total.
5. full-bypass: it never came within the discomfort distance of any human.
6. partly-bypass: everything else (it went around the humans but came close to some).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from crowdplan.evaluation import Trace
from crowdplan.social_metrics import gaps

STRATEGIES = ("full-bypass", "partly-bypass", "follow-pass", "wait-pass", "back-pass", "cross")

CUT_GAP = 0.3  # m, edge to edge
MOVING = 0.3  # m/s
BACK_DIST = 0.5  # m of retreat along the start-goal axis
WAIT_SPEED = 0.3  # m/s
BLOCK_GAP = 1.0  # m
WAIT_TIME = 1.0  # s
FOLLOW_ANGLE = math.radians(30)
FOLLOW_GAP = 1.5  # m
FOLLOW_HEADING = math.radians(45)
FOLLOW_TIME = 1.5  # s
DISCOMFORT = 0.2  # m, the world's discomfort distance (WorldConfig.discomfort_dist)


@dataclass(frozen=True)
class Evidence:
    """The measurements the rules compare with their thresholds (seconds, metres)."""

    collided: bool
    cut_steps: int
    retreat: float
    wait_time: float
    follow_time: float
    min_gap: float


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unsigned angle between vectors (..., 2)."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return np.abs(np.arctan2(cross, np.einsum("...i,...i", a, b)))


def evidence(trace: Trace, outcome: str) -> Evidence:
    """Measure what the rules need from one episode."""
    steps = len(trace.robot_vel)
    dt = trace.dt
    pos = trace.robot_pos[:steps]
    vel = trace.robot_vel
    humans = trace.human_pos[:steps]
    n = humans.shape[1] if humans.ndim == 3 else 0
    h_vel = trace.human_vel[1 : steps + 1] if trace.human_vel is not None else np.zeros_like(humans)
    present = (
        trace.human_present[:steps]
        if trace.human_present is not None
        else np.ones((steps, n), dtype=bool)
    )
    axis = trace.robot_goal - trace.robot_pos[0]
    axis = axis / max(float(np.linalg.norm(axis)), 1e-9)
    speed = np.hypot(*vel.T) if steps else np.zeros(0)
    progress = (trace.robot_pos - trace.robot_pos[0]) @ axis
    retreat = float((np.maximum.accumulate(progress) - progress).max())

    gap = gaps(pos, humans, trace.robot_radius, trace.human_radius, present)
    later = None if trace.human_present is None else trace.human_present[1:]
    all_gap = gaps(
        trace.robot_pos[1:], trace.human_pos[1:], trace.robot_radius, trace.human_radius, later
    )
    min_gap = float(all_gap.min()) if all_gap.size else math.inf
    if n and steps:
        rel = humans - pos[:, None, :]
        side = np.sign(vel[:, None, 0] * rel[..., 1] - vel[:, None, 1] * rel[..., 0])
        near = gap < CUT_GAP
        cut = (speed > MOVING) & (near & (side > 0)).any(axis=1) & (near & (side < 0)).any(axis=1)
        to_goal = trace.robot_goal - pos
        blocked = ((gap < BLOCK_GAP) & (np.einsum("tni,ti->tn", rel, to_goal) > 0)).any(axis=1)
        wait = (speed < WAIT_SPEED) & blocked
        ahead = _angle(rel, np.broadcast_to(vel[:, None, :], rel.shape)) < FOLLOW_ANGLE
        h_speed = np.hypot(h_vel[..., 0], h_vel[..., 1])
        same_way = _angle(h_vel, np.broadcast_to(vel[:, None, :], h_vel.shape)) < FOLLOW_HEADING
        follow = (speed > MOVING) & (
            ahead & same_way & (gap < FOLLOW_GAP) & (h_speed > MOVING)
        ).any(1)
    else:
        cut = wait = follow = np.zeros(steps, dtype=bool)
    return Evidence(
        collided=outcome == "collision",
        cut_steps=int(cut.sum()),
        retreat=retreat,
        wait_time=float(wait.sum() * dt),
        follow_time=float(follow.sum() * dt),
        min_gap=min_gap,
    )


def decide(ev: Evidence) -> str:
    """The strategy the rules assign to measured evidence (module docstring, in order)."""
    if ev.collided or ev.cut_steps:
        return "cross"
    if ev.retreat >= BACK_DIST:
        return "back-pass"
    if ev.wait_time >= WAIT_TIME:
        return "wait-pass"
    if ev.follow_time >= FOLLOW_TIME:
        return "follow-pass"
    if ev.min_gap >= DISCOMFORT:
        return "full-bypass"
    return "partly-bypass"


def classify(trace: Trace, outcome: str) -> str:
    """The strategy of one episode."""
    return decide(evidence(trace, outcome))


def classify_run(records) -> list[str]:
    """The strategy of every episode of an ``evaluation_records.Records``."""
    return [classify(records.trace(k), str(records.outcomes[k])) for k in range(len(records))]


def distribution(strategies: list[str]) -> dict[str, float]:
    """Share of each strategy (all six keys, in table order)."""
    counts = Counter(strategies)
    total = max(len(strategies), 1)
    return {name: counts[name] / total for name in STRATEGIES}


def dominant(strategies: list[str], top: int = 2) -> list[str]:
    """The ``top`` most frequent strategies, most frequent first (ties in table order)."""
    counts = Counter(strategies)
    ranked = sorted(STRATEGIES, key=lambda s: (-counts[s], STRATEGIES.index(s)))
    return [s for s in ranked[:top] if counts[s]]


# The paper's table V (docs/paper.md): dominant strategies of its planners.
PAPER_DOMINANT = {
    "ORCA": ("cross",),
    "CADRL": ("cross", "follow-pass"),
    "LSTM-RL": ("partly-bypass", "follow-pass"),
    "SARL": ("full-bypass", "partly-bypass"),
    "LSTM-A2C": ("back-pass", "wait-pass"),
    "RG-DSAC": ("partly-bypass", "follow-pass"),
    "LSA-DSAC": ("full-bypass", "partly-bypass"),
}
