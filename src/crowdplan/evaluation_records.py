"""Per-episode trajectory records: ``records.npz`` beside ``summary.json`` and ``episodes.jsonl``.

``crowdplan eval --record --out DIR`` writes them; the analyses (strategies, attention) read
them back here instead of running the simulator again. One compressed ``.npz`` holds every
episode's arrays concatenated along time (float32), with each episode's step count; episode k's
steps are rows ``step_offsets[k]:step_offsets[k + 1]`` and its states (one more than steps)
rows ``state_offsets[k]:state_offsets[k + 1]``. The ``format`` entry names the version.
Human velocities and attention scores are stored as float16 (about 3 significant digits), the
other real arrays as float32.

Arrays (E episodes, N humans, S = total steps, S + E = total states):

| key | shape | content |
|---|---|---|
| format | () | ``crowdplan-records/1`` |
| seeds, steps | (E,) | seed and number of steps of each episode |
| outcomes | (E,) | goal, collision or timeout |
| robot_pos | (S + E, 2) | robot position at each state |
| robot_vel | (S, 2) | robot velocity of each step |
| actions | (S,) or (S, 2) | action index (int16) or velocity command of each step |
| d_min | (S,) | swept d_min of each step |
| human_pos, human_vel | (S + E, N, 2) | humans at each state |
| human_present | (S + E, N) | False: absent (masked) human |
| scores | (S, N) | per-human attention of each decision (only for models that have it) |
| robot_goal | (E, 2) | goal |
| human_goal, human_radius | (E, N, 2), (E, N) | humans' first goals and radii |
| robot_radius, dt | () | |
"""

from __future__ import annotations

import io
import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crowdplan.evaluation import EpisodeRecord, Trace, summarize
from crowdplan.io import atomic_write

RECORD_FORMAT = "crowdplan-records/1"
RECORD_FILE, EPISODES_FILE, SUMMARY_FILE = "records.npz", "episodes.jsonl", "summary.json"
_REQUIRED = (
    "seeds",
    "steps",
    "outcomes",
    "robot_pos",
    "robot_vel",
    "actions",
    "d_min",
    "human_pos",
    "human_vel",
    "human_present",
    "robot_goal",
    "human_goal",
    "human_radius",
    "robot_radius",
    "dt",
)
_SUMMARY_TOLERANCE = 1e-6


class RecordError(ValueError):
    """A record file or result folder that cannot be read as this version writes it."""


def _cat(parts: list[np.ndarray], dtype) -> np.ndarray:
    return np.concatenate(parts).astype(dtype, copy=False)


def write_records(path: str | Path, records: list[EpisodeRecord]) -> Path:
    """Write the traces of ``records`` (run with ``record_traces=True``) to one .npz, atomically."""
    path = Path(path)
    traces = [r.trace for r in records]
    if not records or any(t is None or t.actions is None for t in traces):
        raise ValueError("every record needs its trace (run_episodes(..., record_traces=True))")
    with_scores = all(t.scores is not None for t in traces)
    discrete = traces[0].actions.ndim == 1
    arrays = {
        "format": np.array(RECORD_FORMAT),
        "seeds": np.array([r.seed for r in records], dtype=np.int64),
        "steps": np.array([r.steps for r in records], dtype=np.int32),
        "outcomes": np.array([r.outcome for r in records]),
        "robot_pos": _cat([t.robot_pos for t in traces], np.float32),
        "robot_vel": _cat([t.robot_vel for t in traces], np.float32),
        "actions": _cat([t.actions for t in traces], np.int16 if discrete else np.float32),
        "d_min": _cat([t.d_min for t in traces], np.float32),
        "human_pos": _cat([t.human_pos for t in traces], np.float32),
        "human_vel": _cat([t.human_vel for t in traces], np.float16),
        "human_present": _cat([t.human_present for t in traces], bool),
        "robot_goal": np.array([t.robot_goal for t in traces], dtype=np.float32),
        "human_goal": np.array([t.human_goal for t in traces], dtype=np.float32),
        "human_radius": np.array([t.human_radius for t in traces], dtype=np.float32),
        "robot_radius": np.array(traces[0].robot_radius, dtype=np.float32),
        "dt": np.array(traces[0].dt),
    }
    if with_scores:
        arrays["scores"] = _cat([t.scores for t in traces], np.float16)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    atomic_write(path, lambda f: f.write(buffer.getvalue()), mode="wb")
    return path


@dataclass
class Records:
    """The recorded episodes of one result folder (``read_records``)."""

    path: Path
    arrays: dict[str, np.ndarray]
    step_offsets: np.ndarray
    state_offsets: np.ndarray

    def __len__(self) -> int:
        return len(self.arrays["seeds"])

    @property
    def seeds(self) -> np.ndarray:
        return self.arrays["seeds"]

    @property
    def outcomes(self) -> np.ndarray:
        return self.arrays["outcomes"]

    @property
    def has_scores(self) -> bool:
        return "scores" in self.arrays

    def steps_of(self, key: str, k: int) -> np.ndarray:
        """Rows of a per-step array (robot_vel, actions, d_min, scores) for episode ``k``."""
        return self.arrays[key][self.step_offsets[k] : self.step_offsets[k + 1]]

    def states_of(self, key: str, k: int) -> np.ndarray:
        """Rows of a per-state array (robot_pos, human_*) for episode ``k``."""
        return self.arrays[key][self.state_offsets[k] : self.state_offsets[k + 1]]

    def trace(self, k: int) -> Trace:
        """Episode ``k`` (0-based position in the file) as an ``evaluation.Trace`` (float64)."""
        a = self.arrays

        def f64(x: np.ndarray) -> np.ndarray:
            return x.astype(np.float64)

        return Trace(
            robot_pos=f64(self.states_of("robot_pos", k)),
            robot_vel=f64(self.steps_of("robot_vel", k)),
            robot_goal=f64(a["robot_goal"][k]),
            robot_radius=float(a["robot_radius"]),
            human_pos=f64(self.states_of("human_pos", k)),
            human_goal=f64(a["human_goal"][k]),
            human_radius=f64(a["human_radius"][k]),
            scores=f64(self.steps_of("scores", k)) if self.has_scores else None,
            dt=float(a["dt"]),
            human_vel=f64(self.states_of("human_vel", k)),
            human_present=self.states_of("human_present", k),
            actions=self.steps_of("actions", k),
            d_min=f64(self.steps_of("d_min", k)),
        )

    def index_of(self, seed: int) -> int:
        """Position of the episode of ``seed``."""
        hits = np.flatnonzero(self.seeds == seed)
        if not hits.size:
            raise RecordError(f"{self.path}: no episode with seed {seed}")
        return int(hits[0])


def read_records(path: str | Path) -> Records:
    """Read and check a records.npz; RecordError names the file and what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(f"{path}: no such record file (write one with crowdplan eval --record)")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
        raise RecordError(f"{path}: not a record file ({error})") from None
    version = str(arrays.get("format", "none"))
    if version != RECORD_FORMAT:
        raise RecordError(
            f"{path}: record format {version!r}, this version reads {RECORD_FORMAT!r}; "
            "record the evaluation again with crowdplan eval --record"
        )
    missing = [key for key in _REQUIRED if key not in arrays]
    if missing:
        raise RecordError(f"{path}: array(s) {', '.join(missing)} missing")
    steps = arrays["steps"].astype(np.int64)
    e = len(arrays["seeds"])
    step_offsets = np.concatenate([[0], np.cumsum(steps)])
    state_offsets = np.concatenate([[0], np.cumsum(steps + 1)])
    expected = {"steps": e, "outcomes": e, "robot_goal": e, "human_goal": e, "human_radius": e}
    expected.update({key: step_offsets[-1] for key in ("robot_vel", "actions", "d_min")})
    expected.update(
        {key: state_offsets[-1] for key in ("robot_pos", "human_pos", "human_vel", "human_present")}
    )
    if "scores" in arrays:
        expected["scores"] = step_offsets[-1]
    for key, rows in expected.items():
        if len(arrays[key]) != rows:
            raise RecordError(
                f"{path}: array {key} has {len(arrays[key])} rows, the episodes' step counts "
                f"need {rows} (file cut short or written by other code)"
            )
    return Records(path, arrays, step_offsets, state_offsets)


def read_episodes(path: str | Path) -> list[EpisodeRecord]:
    """The records of an episodes.jsonl; RecordError names the file and line of a bad one."""
    path = Path(path)
    if not path.is_file():
        raise RecordError(f"{path}: no such file")
    records = []
    with open(path) as f:
        for line_no, line in enumerate(f, start=1):
            if not line.strip():
                continue
            try:
                records.append(EpisodeRecord.from_json(json.loads(line)))
            except (ValueError, TypeError) as error:
                raise RecordError(f"{path}, line {line_no}: {error}") from None
    return records


def _close(a: float | None, b: float) -> bool:
    a = math.nan if a is None else a
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= _SUMMARY_TOLERANCE * max(1.0, abs(a), abs(b))


def check_summary(folder: str | Path, episodes: list[EpisodeRecord]) -> dict:
    """summary.json of ``folder``, checked against its episodes (every metric it holds)."""
    path = Path(folder) / SUMMARY_FILE
    if not path.is_file():
        raise RecordError(f"{path}: no such file")
    try:
        summary = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise RecordError(f"{path}, line {error.lineno}: {error.msg}") from None
    again = summarize(episodes)
    for key, entry in summary.items():
        if key == "meta" or key not in again:
            continue
        if not isinstance(entry, dict) or not _close(entry.get("value"), again[key]["value"]):
            raise RecordError(
                f"{path}: {key} is {entry.get('value') if isinstance(entry, dict) else entry!r}, "
                f"its {EPISODES_FILE} gives {again[key]['value']!r}"
            )
    return summary


@dataclass
class RecordedRun:
    """A result folder with its summary, episodes and trajectory records, all consistent."""

    folder: Path
    summary: dict
    episodes: list[EpisodeRecord]
    records: Records

    @property
    def name(self) -> str:
        return self.summary.get("meta", {}).get("policy", self.folder.name)


def load_recorded(folder: str | Path) -> RecordedRun:
    """Read a result folder written by ``crowdplan eval --record`` and check that its three
    files agree: the same episodes (seed, outcome, steps) in the same order, and a summary that
    its episodes reproduce."""
    folder = Path(folder)
    if not (folder / RECORD_FILE).is_file():
        raise RecordError(
            f"{folder}: no {RECORD_FILE} (a folder without trajectories); write one with "
            f"crowdplan eval --record --out {folder}"
        )
    records = read_records(folder / RECORD_FILE)
    episodes = read_episodes(folder / EPISODES_FILE)
    summary = check_summary(folder, episodes)
    if len(episodes) != len(records):
        seeds = {r.seed for r in episodes} ^ set(records.seeds.tolist())
        raise RecordError(
            f"{folder}: {EPISODES_FILE} has {len(episodes)} episodes, {RECORD_FILE} has "
            f"{len(records)}; seeds in only one of them: {sorted(seeds)[:10]}"
        )
    for k, episode in enumerate(episodes):
        seed, outcome, steps = records.seeds[k], records.outcomes[k], records.arrays["steps"][k]
        if (episode.seed, episode.outcome, episode.steps) != (seed, outcome, steps):
            raise RecordError(
                f"{folder / EPISODES_FILE}, episode {k + 1} (seed {episode.seed}): "
                f"{episode.outcome} after {episode.steps} steps, but {RECORD_FILE} has seed "
                f"{seed}, {outcome} after {steps} steps"
            )
    return RecordedRun(folder, summary, episodes, records)


def recorded_folders(root: str | Path) -> list[Path]:
    """Every folder under ``root`` that holds a records.npz, sorted."""
    return sorted(p.parent for p in Path(root).rglob(RECORD_FILE))
