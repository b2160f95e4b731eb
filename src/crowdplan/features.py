"""Robot-centric features (SPEC.md section 3): the one transform used by training, evaluation,
rendering and deployment.

The frame is CrowdNav's: origin at the robot, x-axis pointing from the robot to its goal.
Per human the 13-d row is the 6-d robot part followed by the 7-d human part:

    robot part  (6): distance to goal, v_pref, theta', r, vx', vy'
    human part  (7): px', py', vx', vy', r_h, distance robot-human, r + r_h

theta' is the heading relative to the goal direction for unicycle robots and 0 for holonomic ones,
whose heading carries no information (as in CrowdNav).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

ROBOT_FEAT_DIM = 6
HUMAN_FEAT_DIM = 7


class Features(NamedTuple):
    """Encoder input: robot (E, 6), humans (E, N, 7) with padded rows zeroed, mask (E, N)."""

    robot: np.ndarray
    humans: np.ndarray
    mask: np.ndarray


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Map angles to [-pi, pi)."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


def robot_centric(
    robot: np.ndarray, humans: np.ndarray, mask: np.ndarray, unicycle: bool = False
) -> Features:
    """Rotate raw observations into the robot-centric frame.

    Args:
        robot: (..., 9) robot full state px, py, vx, vy, r, gx, gy, v_pref, theta.
        humans: (..., N, 5) observable human states px, py, vx, vy, r.
        mask: (..., N) True for real humans.
        unicycle: whether theta' carries the heading (unicycle) or is 0 (holonomic).
    """
    robot = np.asarray(robot, dtype=np.float64)
    humans = np.asarray(humans, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    px, py, vx, vy, r, gx, gy, v_pref, theta = np.moveaxis(robot, -1, 0)
    dx, dy = gx - px, gy - py
    rot = np.arctan2(dy, dx)
    cos, sin = np.cos(rot), np.sin(rot)
    theta_rel = wrap_angle(theta - rot) if unicycle else np.zeros_like(theta)
    robot_feat = np.stack(
        [np.hypot(dx, dy), v_pref, theta_rel, r, vx * cos + vy * sin, vy * cos - vx * sin], axis=-1
    )

    c, s = cos[..., None], sin[..., None]
    hx = humans[..., 0] - px[..., None]
    hy = humans[..., 1] - py[..., None]
    hvx, hvy, hr = humans[..., 2], humans[..., 3], humans[..., 4]
    human_feat = np.stack(
        [
            hx * c + hy * s,
            hy * c - hx * s,
            hvx * c + hvy * s,
            hvy * c - hvx * s,
            hr,
            np.hypot(hx, hy),
            hr + r[..., None],
        ],
        axis=-1,
    )
    human_feat = np.where(mask[..., None], human_feat, 0.0)
    return Features(robot_feat.astype(np.float32), human_feat.astype(np.float32), mask)
