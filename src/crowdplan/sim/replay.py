"""Replay scenario: humans follow recorded ETH/UCY pedestrian trajectories (non-reactive).

Recordings are text files with one row per pedestrian and annotated frame: ``frame id x y``
(tab or space separated, metres). Five public scenes ship in ``sim/data/ethucy/`` (SOURCE.md
there gives their origin, licence notes and checksums). eth and hotel are for development and
training; zara1, zara2 and univ are held out (``HELD_OUT``): measure on them, never train, tune or
select on them.

Time bases differ: hotel and the UCY scenes have 10 frame ids per 0.4 s; the distributed
biwi_eth.txt is the 0.4 s ETH annotation interpolated at every 10th frame id of a 15 fps video, so
its rows are 10/15 s apart (0.4/6 s per frame id).

A replay case is a pure function of its seed: a scene, a start time and one recorded pedestrian
(the anchor) are drawn; the robot's 8 m path crosses the anchor's walking direction at right
angles, placed so that a robot at its preferred speed would reach the crossing point when the
anchor does. The pedestrians whose recorded positions come within ``NEAR_PATH`` of the path
during the episode (closest first, at most ``WorldConfig.humans``) are replayed, linearly
interpolated at the world's time step; a case needs ``replay_min_humans`` of them and a start
that is clear of everyone. The scene is then moved so that the robot goes from (0, -R) to (0, R)
with R = 4 (``goal_rotation`` / ``random_goal_direction`` turn it like any other scenario).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.sim.initial_state import PLACEMENT_MARGIN, REPLAY, InitialState, PlacementError

DATA_DIR = Path(__file__).resolve().parent / "data" / "ethucy"
ETH_SECONDS_PER_FRAME = 0.4 / 6
UCY_SECONDS_PER_FRAME = 0.04
SCENES = {
    "eth": ("biwi_eth.txt", ETH_SECONDS_PER_FRAME),
    "hotel": ("biwi_hotel.txt", UCY_SECONDS_PER_FRAME),
    "zara1": ("crowds_zara01.txt", UCY_SECONDS_PER_FRAME),
    "zara2": ("crowds_zara02.txt", UCY_SECONDS_PER_FRAME),
    "univ": ("students003.txt", UCY_SECONDS_PER_FRAME),
}
TRAINING_SCENES = ("eth", "hotel")
HELD_OUT = ("zara1", "zara2", "univ")
FRAME_STEP = 10  # frame ids between consecutive rows of one pedestrian
PATH_LENGTH = 8.0
NEAR_PATH = 2.0  # metres: pedestrians closer than this to the robot's path are replayed
MIN_ANCHOR_SPEED = 0.3  # m/s: the anchor pedestrian must be walking


class TrajectoryFileError(ValueError):
    """A recording that cannot be read; the message names the file, the line and the fix."""


@dataclass(frozen=True)
class Recording:
    """Pedestrian tracks of one file: per pedestrian its sample times (s) and positions (m)."""

    path: Path
    ids: tuple[float, ...]
    times: tuple[np.ndarray, ...]
    positions: tuple[np.ndarray, ...]

    @property
    def start(self) -> np.ndarray:
        return np.array([t[0] for t in self.times])

    @property
    def end(self) -> np.ndarray:
        return np.array([t[-1] for t in self.times])


def load_recording(
    path: str | Path, seconds_per_frame: float, frame_step: int = FRAME_STEP
) -> Recording:
    """Read and check a ``frame id x y`` file.

    Rows must be sorted by frame, each pedestrian at most once per frame and every
    ``frame_step`` frame ids from its first to its last row (no gaps).
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as error:
        raise TrajectoryFileError(f"cannot read trajectory file {path}: {error}") from error
    tracks: dict[float, list[tuple[float, float, float]]] = {}
    last_frame, last_line = -np.inf, 0
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        where = f"{path}, line {number}"
        parts = text.split()
        if len(parts) != 4:
            raise TrajectoryFileError(
                f"{where}: expected 4 columns (frame, pedestrian id, x, y), got {len(parts)} "
                f"in {text!r}; keep only those four columns, separated by tabs or spaces"
            )
        try:
            frame, ped, x, y = (float(p) for p in parts)
        except ValueError:
            raise TrajectoryFileError(
                f"{where}: {text!r} is not four numbers (frame, pedestrian id, x, y); "
                "remove header lines or prefix them with '#'"
            ) from None
        if not np.all(np.isfinite([frame, ped, x, y])):
            raise TrajectoryFileError(f"{where}: {text!r} holds a non-finite number; fix the row")
        if frame < last_frame:
            raise TrajectoryFileError(
                f"{where}: frame {frame:g} comes after frame {last_frame:g} (line {last_line}); "
                "rows must be sorted by frame: sort the file by its first column"
            )
        rows = tracks.setdefault(ped, [])
        if rows and rows[-1][0] == frame:
            raise TrajectoryFileError(
                f"{where}: pedestrian {ped:g} appears twice in frame {frame:g}; "
                "remove the duplicate row"
            )
        if rows and frame - rows[-1][0] != frame_step:
            raise TrajectoryFileError(
                f"{where}: pedestrian {ped:g} jumps from frame {rows[-1][0]:g} to {frame:g}, but "
                f"its rows must be {frame_step} frame ids apart; fill the missing rows or give "
                "the part after the gap its own pedestrian id"
            )
        rows.append((frame, x, y))
        last_frame, last_line = frame, number
    if not tracks:
        raise TrajectoryFileError(f"{path} holds no trajectory rows (frame, pedestrian id, x, y)")
    ids = tuple(sorted(tracks))
    arrays = [np.array(tracks[i]) for i in ids]
    return Recording(
        path=path,
        ids=ids,
        times=tuple(a[:, 0] * seconds_per_frame for a in arrays),
        positions=tuple(a[:, 1:3] for a in arrays),
    )


@functools.cache
def scene_recording(name: str) -> Recording:
    """The shipped recording of an ETH/UCY scene (eth, hotel, zara1, zara2, univ)."""
    if name not in SCENES:
        raise ValueError(f"unknown replay scene {name!r}; scenes are {sorted(SCENES)}")
    filename, seconds_per_frame = SCENES[name]
    return load_recording(DATA_DIR / filename, seconds_per_frame)


def interpolate(recording: Recording, index: int, times: np.ndarray):
    """Positions (T, 2) of one pedestrian at ``times`` (held at the ends) and presence (T,)."""
    t, xy = recording.times[index], recording.positions[index]
    present = (times >= t[0] - 1e-9) & (times <= t[-1] + 1e-9)
    pos = np.stack([np.interp(times, t, xy[:, 0]), np.interp(times, t, xy[:, 1])], axis=1)
    return pos, present


def replay_case(config: WorldConfig, seed: int) -> InitialState:
    """The replay case of this seed (see the module docstring)."""
    rng = np.random.default_rng(seed)
    name = config.replay_scenes[int(rng.integers(len(config.replay_scenes)))]
    recording = scene_recording(name)
    return place_case(config, recording, rng, label=f"scene {name!r}")


def place_case(
    config: WorldConfig, recording: Recording, rng: np.random.Generator, label: str = ""
) -> InitialState:
    """Place the robot's path across the recorded flow of ``recording`` (draws from ``rng``)."""
    frames = config.max_steps + 1
    duration = config.max_steps * config.dt
    starts, ends = recording.start, recording.end
    first, last = starts.min(), ends.max()
    label = label or str(recording.path)
    radius = config.human_radius
    for _ in range(config.placement_tries):
        t0 = rng.uniform(first, max(first, last - duration / 2))
        t_cross = rng.uniform(2.0, 6.0)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        times = t0 + np.arange(frames) * config.dt
        alive = np.flatnonzero((starts <= times[-1]) & (ends >= times[0]))
        anchors = alive[(starts[alive] <= t0 + t_cross - 0.5) & (ends[alive] >= t0 + t_cross + 0.5)]
        if not len(anchors):
            continue
        anchor = int(anchors[rng.integers(len(anchors))])
        (a0, a1), _ = interpolate(recording, anchor, t0 + t_cross + np.array([-0.5, 0.5]))
        heading = a1 - a0
        speed = np.hypot(*heading)
        if speed < MIN_ANCHOR_SPEED:
            continue
        along = sign * np.array([-heading[1], heading[0]]) / speed  # across the anchor's walk
        to_cross = np.clip(t_cross * config.robot_v_pref, 1.0, PATH_LENGTH - 1.0)
        start = (a0 + a1) / 2 - along * to_cross
        goal = start + along * PATH_LENGTH
        tracks, presence, near = [], [], []
        for index in alive:
            pos, present = interpolate(recording, int(index), times)
            distance = _segment_distance(pos[present], start, goal)
            if distance.size and distance.min() < NEAR_PATH:
                tracks.append(pos)
                presence.append(present)
                near.append(distance.min())
        if len(near) < config.replay_min_humans:
            continue
        order = np.argsort(near, kind="stable")[: config.humans]
        track, present = np.array(tracks)[order], np.array(presence)[order]
        gap = np.hypot(*(track[:, 0] - start).T) - radius - config.robot_radius
        if np.any(present[:, 0] & (gap < PLACEMENT_MARGIN)):
            continue
        return _normalised(config, start, goal, track, present)
    raise PlacementError(
        f"could not place a replay case in {label} ({recording.path}) after "
        f"{config.placement_tries} tries (placement_tries): too few walking pedestrians come "
        f"within {NEAR_PATH} m of an 8 m path (replay_min_humans={config.replay_min_humans}); "
        "use a recording with more pedestrians or lower replay_min_humans"
    )


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    u = np.clip((points - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.hypot(*(points - a - u[:, None] * ab).T)


def _normalised(config, start, goal, track, present) -> InitialState:
    """Move the case so that the robot goes from (0, -R) to (0, R) along +y."""
    along = (goal - start) / PATH_LENGTH
    angle = np.pi / 2 - np.arctan2(along[1], along[0])
    cos, sin = np.cos(angle), np.sin(angle)
    rot = np.array([[cos, -sin], [sin, cos]])
    track = (track - (start + goal) / 2) @ rot.T
    n = len(track)
    last = np.array([np.flatnonzero(p)[-1] for p in present], dtype=np.int64)
    velocity = np.where(
        (present[:, 0] & present[:, 1])[:, None], (track[:, 1] - track[:, 0]) / config.dt, 0.0
    )
    half = PATH_LENGTH / 2
    return InitialState(
        robot_pos=np.array([0.0, -half]),
        robot_goal=np.array([0.0, half]),
        human_pos=track[:, 0].copy(),
        human_goal=track[np.arange(n), last].copy(),
        human_radius=np.full(n, config.human_radius),
        human_v_pref=np.full(n, config.human_v_pref),
        human_kind=np.full(n, REPLAY, dtype=np.int64),
        human_vel=velocity,
        track=track,
        track_present=present,
    )
