"""Velocities from timestamped poses: filtered finite differences that reject bad samples.

Each tracked agent keeps its last accepted pose. A new pose gives the raw velocity
``(p - p_last) / (t - t_last)`` over the real time between the two samples (so jitter in the
arrival times does not bias it), smoothed by an exponential filter with time constant ``tau``
(``tau = 0``: the plain finite difference). A sample is rejected, and the track marked faulty
until the next good sample, when it is not finite, not newer than the last one, or implies a
speed above ``max_speed`` (a jump: a swapped marker, a re-initialised tracker). After a jump the
new pose becomes the anchor with velocity 0, so a track never stays stuck on an old position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class Track:
    """Filtered state of one agent; ``fault`` names the last rejected sample's problem ("" if
    the last sample was accepted)."""

    t: float
    x: float
    y: float
    yaw: float
    vx: float = 0.0
    vy: float = 0.0
    fault: str = ""


class VelocityEstimator:
    """Per-agent tracks from pose samples.

    Args:
        tau: time constant (s) of the exponential smoothing of the finite differences.
        max_speed: speeds above this (m/s) between two samples are rejected as jumps.
    """

    def __init__(self, tau: float = 0.0, max_speed: float = 5.0):
        if tau < 0 or max_speed <= 0:
            raise ValueError(f"need tau >= 0 and max_speed > 0, got {tau} and {max_speed}")
        self.tau = tau
        self.max_speed = max_speed
        self.tracks: dict[str, Track] = {}

    def update(self, agent: str, t: float, x: float, y: float, yaw: float) -> str:
        """Feed one pose sample; returns "" if accepted, else why it was rejected."""
        track = self.tracks.get(agent)
        if not all(math.isfinite(v) for v in (t, x, y, yaw)):
            reason = "pose or time is not finite"
        elif track is None:
            self.tracks[agent] = Track(t, x, y, yaw)
            return ""
        elif t <= track.t:
            reason = f"time did not advance ({t:.3f} s after {track.t:.3f} s)"
            if t == track.t and (x, y, yaw) == (track.x, track.y, track.yaw):
                return ""  # the same sample delivered twice is harmless
        else:
            dt = t - track.t
            raw_vx, raw_vy = (x - track.x) / dt, (y - track.y) / dt
            if math.hypot(raw_vx, raw_vy) > self.max_speed:
                reason = f"jumped {math.hypot(x - track.x, y - track.y):.2f} m in {dt:.3f} s"
                self.tracks[agent] = Track(t, x, y, yaw, fault=reason)
                return reason
            if self.tau > 0:
                gain = dt / (self.tau + dt)
                raw_vx = track.vx + gain * (raw_vx - track.vx)
                raw_vy = track.vy + gain * (raw_vy - track.vy)
            track.vx, track.vy = raw_vx, raw_vy
            track.t, track.x, track.y, track.yaw, track.fault = t, x, y, yaw, ""
            return ""
        if track is not None:
            track.fault = reason
        return reason
