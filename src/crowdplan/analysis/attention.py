"""Attention of a model over the humans (the paper's table III and figure 7), from records.

Every decision of a recorded episode gives one sample per present human: the attention score the
model gave that human, and what the model saw in that state: the edge-to-edge gap, the closing
speed (how fast the centre distance shrinks, m/s) and the constant-velocity time to collision
(the robot moving at its velocity of the previous step, at rest before the first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crowdplan.analysis.stats import spearman
from crowdplan.social_metrics import gaps, ttc_matrix


@dataclass
class AttentionSamples:
    """One row per (episode, decision, present human)."""

    score: np.ndarray
    gap: np.ndarray
    closing_speed: np.ndarray
    ttc: np.ndarray
    top_is_nearest: np.ndarray  # per decision with >= 2 humans: the top score is the nearest's
    top_is_soonest: np.ndarray  # ... the top score is the smallest time to collision's
    humans_per_decision: np.ndarray


def samples(records) -> AttentionSamples:
    """Attention samples of every episode of an ``evaluation_records.Records`` with scores."""
    if not records.has_scores:
        raise ValueError(f"{records.path}: the recorded model has no attention scores")
    cols: dict[str, list] = {k: [] for k in ("score", "gap", "closing", "ttc", "near", "soon", "n")}
    for k in range(len(records)):
        tr = records.trace(k)
        steps = len(tr.robot_vel)
        pos, humans = tr.robot_pos[:steps], tr.human_pos[:steps]
        robot_vel = np.vstack([np.zeros((1, 2)), tr.robot_vel[: steps - 1]])
        h_vel = tr.human_vel[:steps]
        present = tr.human_present[:steps]
        gap = gaps(pos, humans, tr.robot_radius, tr.human_radius, present)
        ttc = ttc_matrix(pos, robot_vel, humans, h_vel, tr.robot_radius, tr.human_radius, present)
        rel_pos = humans - pos[:, None, :]
        rel_vel = h_vel - robot_vel[:, None, :]
        dist = np.maximum(np.linalg.norm(rel_pos, axis=-1), 1e-9)
        closing = -np.einsum("tni,tni->tn", rel_pos, rel_vel) / dist
        score = np.where(present, tr.scores, -np.inf)
        cols["score"].append(tr.scores[present])
        cols["gap"].append(gap[present])
        cols["closing"].append(closing[present])
        cols["ttc"].append(ttc[present])
        many = present.sum(axis=1) >= 2
        top = score.argmax(axis=1)
        cols["near"].append((top == gap.argmin(axis=1))[many])
        soonest = np.where(np.isfinite(ttc).any(axis=1), ttc.argmin(axis=1), -1)
        cols["soon"].append((top == soonest)[many & (soonest >= 0)])
        cols["n"].append(present.sum(axis=1)[many])
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    return AttentionSamples(
        cat["score"], cat["gap"], cat["closing"], cat["ttc"], cat["near"], cat["soon"], cat["n"]
    )


def correlations(s: AttentionSamples) -> dict[str, float]:
    """Spearman correlation of attention with gap, closing speed and time to collision (an
    infinite time ranks above every finite one), and how often the most attended human is the
    nearest / the soonest to collide, beside the chance level 1 / (humans present)."""
    return {
        "samples": float(s.score.size),
        "spearman_gap": spearman(s.score, s.gap),
        "spearman_closing_speed": spearman(s.score, s.closing_speed),
        "spearman_ttc": spearman(s.score, s.ttc),
        "top_is_nearest": float(s.top_is_nearest.mean()) if s.top_is_nearest.size else math.nan,
        "top_is_soonest": float(s.top_is_soonest.mean()) if s.top_is_soonest.size else math.nan,
        "chance": float((1 / s.humans_per_decision).mean())
        if s.humans_per_decision.size
        else math.nan,
    }


def binned_means(x: np.ndarray, y: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``y`` in each bin of ``x`` (nan for an empty bin), and the bin centres."""
    idx = np.digitize(x, edges) - 1
    means = np.array(
        [y[idx == b].mean() if (idx == b).any() else np.nan for b in range(len(edges) - 1)]
    )
    return (edges[:-1] + edges[1:]) / 2, means
