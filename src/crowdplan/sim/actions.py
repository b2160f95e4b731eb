"""The one discrete action table (SPEC.md section 2): stop + 16 directions x 5 speeds."""

from __future__ import annotations

import numpy as np

N_DIRECTIONS = 16
N_SPEEDS = 5
N_ACTIONS = 1 + N_DIRECTIONS * N_SPEEDS


def speed_levels(v_pref: float, sampling: str = "linear") -> np.ndarray:
    """The five speeds: {0.2, ..., 1.0} * v_pref, or CrowdNav's (e^(i/5) - 1) / (e - 1) * v_pref."""
    i = np.arange(1, N_SPEEDS + 1, dtype=np.float64)
    if sampling == "linear":
        return i / N_SPEEDS * v_pref
    if sampling == "exponential":
        return (np.exp(i / N_SPEEDS) - 1.0) / (np.e - 1.0) * v_pref
    raise ValueError(f"speed_sampling must be 'linear' or 'exponential', got {sampling!r}")


def direction_levels(kinematics: str = "holonomic") -> np.ndarray:
    """The 16 directions.

    Holonomic: absolute headings k*pi/8, k = 0..15, in the world frame.
    Unicycle: rotations of the current heading, evenly spaced in [-pi/4, pi/4] (CrowdNav).
    """
    if kinematics == "holonomic":
        return np.arange(N_DIRECTIONS, dtype=np.float64) * (2 * np.pi / N_DIRECTIONS)
    if kinematics == "unicycle":
        return np.linspace(-np.pi / 4, np.pi / 4, N_DIRECTIONS)
    raise ValueError(f"kinematics must be 'holonomic' or 'unicycle', got {kinematics!r}")


def action_table(
    v_pref: float = 1.0, kinematics: str = "holonomic", sampling: str = "linear"
) -> np.ndarray:
    """(81, 2) array of (speed, angle); row 0 is stop, row 1 + d*5 + s is direction d, speed s."""
    speeds = speed_levels(v_pref, sampling)
    angles = direction_levels(kinematics)
    table = np.zeros((N_ACTIONS, 2))
    table[1:, 0] = np.tile(speeds, N_DIRECTIONS)
    table[1:, 1] = np.repeat(angles, N_SPEEDS)
    return table


def check_actions(actions: np.ndarray) -> np.ndarray:
    """Validate integer action indices, returning them as int64."""
    actions = np.asarray(actions)
    if actions.dtype.kind not in "iu":
        raise ValueError(
            f"actions must be integers in 0..{N_ACTIONS - 1}, got dtype {actions.dtype}"
        )
    if actions.size and (actions.min() < 0 or actions.max() >= N_ACTIONS):
        bad = actions[(actions < 0) | (actions >= N_ACTIONS)][0]
        raise ValueError(f"action {int(bad)} is outside the valid range 0..{N_ACTIONS - 1}")
    return actions.astype(np.int64)
