"""The evaluation harness and the one place where metrics are defined (docs/metrics.md).

Episodes run batched: up to ``batch_size`` environments step together, each finished environment
is frozen until the whole batch is done. The same seeds give identical records. A policy with a
``bind_world(world)`` method is handed each batch's ``World`` before its first step.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.io import write_json, write_jsonl
from crowdplan.policy import Policy
from crowdplan.sim.world import OUTCOME_NAMES, RUNNING, World
from crowdplan.social_metrics import episode_metrics, linear_jerk

TEST_SEED_BASE, TEST_CASES = 1000, 500
# Validation uses the first 100 cases unless a run asks for more (val_episodes); cases 100..999
# are also the shield's tuning seeds (crowdplan.analysis.shield_tuning): both are development
# cases, never test cases.
VAL_SEED_BASE, VAL_CASES, VAL_DEFAULT_CASES = 0, 1000, 100
REPORT_GAMMA = 0.95  # discount of the "mean reward" metric: 0.95^(t * dt * v_pref)
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Split:
    """A fixed set of evaluation cases: case k is the episode of seed ``seed_base + k``;
    ``default_cases`` (all of them unless given) are the ones played when no count is asked."""

    name: str
    seed_base: int
    cases: int
    default_cases: int | None = None

    def seed(self, case: int) -> int:
        """Seed of case ``case``; refuses cases outside the split."""
        if not 0 <= case < self.cases:
            raise ValueError(
                f"the {self.name} split has cases 0..{self.cases - 1} "
                f"(seeds {self.seed_base}..{self.seed_base + self.cases - 1}), got case {case}"
            )
        return self.seed_base + case

    def seeds(self, episodes: int | None = None) -> list[int]:
        """Seeds of the first ``episodes`` cases (by default ``default_cases``)."""
        if episodes is None:
            episodes = self.cases if self.default_cases is None else self.default_cases
        if not 1 <= episodes <= self.cases:
            raise ValueError(
                f"the {self.name} split has {self.cases} cases "
                f"(seeds {self.seed_base}..{self.seed_base + self.cases - 1}); "
                f"episodes must be in 1..{self.cases}, got {episodes}"
            )
        return list(range(self.seed_base, self.seed_base + episodes))


# Training draws seeds from 2000 on (sim.env), so the two splits never meet training episodes.
SPLITS = {
    "test": Split("test", TEST_SEED_BASE, TEST_CASES),
    "val": Split("val", VAL_SEED_BASE, VAL_CASES, VAL_DEFAULT_CASES),
}


def test_seeds(episodes: int = TEST_CASES) -> list[int]:
    """Seeds of the first ``episodes`` test cases (case k -> seed 1000 + k, k < 500)."""
    return SPLITS["test"].seeds(episodes)


def validation_seeds(episodes: int = VAL_DEFAULT_CASES) -> list[int]:
    """Seeds of the first ``episodes`` validation cases (case k -> seed k, k < 1000)."""
    return SPLITS["val"].seeds(episodes)


@dataclass
class Trace:
    """Trajectory of one episode, for rendering and strategy analysis."""

    robot_pos: np.ndarray  # (T+1, 2)
    robot_vel: np.ndarray  # (T, 2)
    robot_goal: np.ndarray  # (2,)
    robot_radius: float
    human_pos: np.ndarray  # (T+1, N, 2)
    human_goal: np.ndarray  # (N, 2)
    human_radius: np.ndarray  # (N,)
    scores: np.ndarray | None  # (T, N) per-human scores (attention) at each step
    dt: float
    human_vel: np.ndarray | None = None  # (T+1, N, 2) velocity each human had at each state
    human_present: np.ndarray | None = None  # (T+1, N) False: absent (masked) human
    actions: np.ndarray | None = None  # (T,) action indices or (T, 2) velocity commands
    d_min: np.ndarray | None = None  # (T,) swept d_min of each step


@dataclass
class EpisodeRecord:
    """Per-episode facts from which every metric is computed."""

    seed: int
    outcome: str
    steps: int
    time: float
    discounted_return: float
    total_reward: float
    path_length: float
    spl: float
    min_distance: float  # smallest swept d_min over the episode (inf with no humans)
    discomfort_steps: int
    discomfort_distance_sum: float  # sum of d_min over discomfort steps
    jerk: float  # mean |change of acceleration| (m/s^3) over the episode
    # Social metrics (crowdplan.social_metrics); nan when the episode's trajectory is unknown.
    path_irregularity: float = math.nan
    angular_jerk: float = math.nan
    personal_space_intrusion: float = math.nan
    min_ttc: float = math.nan  # inf (null in JSON) when never on a collision course
    mean_human_distance: float = math.nan
    trace: Trace | None = field(default=None, repr=False)

    def to_json(self) -> dict:
        row = asdict(self)
        row.pop("trace")
        row["min_distance"] = None if math.isinf(self.min_distance) else self.min_distance
        return row

    @classmethod
    def from_json(cls, row: dict) -> EpisodeRecord:
        """The record of one ``episodes.jsonl`` line (null: inf for distances and times to
        collision, nan for a social metric the line does not have)."""
        names = {f.name for f in fields(cls)} - {"trace"}
        unknown = set(row) - names
        if unknown:
            raise ValueError(f"unknown field(s) {', '.join(sorted(unknown))}")
        values = dict(row)
        for key in ("min_distance", "min_ttc"):
            if key in values and values[key] is None:
                values[key] = math.inf
        for key in names - set(values):
            if key not in _SOCIAL:
                raise ValueError(f"field {key!r} is missing")
        return cls(**{k: math.nan if v is None else v for k, v in values.items()})


_SOCIAL = (
    "path_irregularity",
    "angular_jerk",
    "personal_space_intrusion",
    "min_ttc",
    "mean_human_distance",
)


def run_episodes(
    policy: Policy,
    config: WorldConfig,
    seeds: list[int],
    batch_size: int = 100,
    record_traces: bool = False,
    on_batch: Callable[[list[EpisodeRecord]], None] | None = None,
) -> list[EpisodeRecord]:
    """Run one episode per seed with ``policy``; returns records in seed order.

    ``on_batch`` is called with the records of each finished batch (for progress reports).
    """
    records: list[EpisodeRecord] = []
    for start in range(0, len(seeds), batch_size):
        chunk = seeds[start : start + batch_size]
        batch = _run_batch(policy, config, chunk, record_traces)
        records.extend(batch)
        if on_batch is not None:
            on_batch(batch)
    return records


def _run_batch(policy, config: WorldConfig, seeds, record_traces) -> list[EpisodeRecord]:
    world = World(config, len(seeds))
    world.reset(seeds)
    if hasattr(policy, "bind_world"):  # planners that query the simulator (oracle lookahead)
        policy.bind_world(world)
    e = len(seeds)
    active = np.ones(e, dtype=bool)
    outcome = np.full(e, RUNNING)
    rewards, d_mins, vels, actions, scores = [], [], [], [], []
    robot_pos, human_pos = [world.robot_pos.copy()], [world.human_pos.copy()]
    human_vel, present = [world.human_vel.copy()], [world.human_present.copy()]
    while active.any():
        out = policy.act(*world.observe())
        result = world.step(out.actions, active)
        rewards.append(result.reward)
        d_mins.append(np.where(active, result.d_min, np.nan))
        vels.append(np.where(active[:, None], world.robot_vel, np.nan))
        robot_pos.append(world.robot_pos.copy())
        human_pos.append(world.human_pos.copy())
        human_vel.append(world.human_vel.copy())
        present.append(world.human_present.copy())
        if record_traces:
            actions.append(np.asarray(out.actions).copy())
            scores.append(out.scores)
        outcome = np.where(active, result.outcome, outcome)
        active &= result.outcome == RUNNING
    rewards_arr, d_min_arr, vel_arr = np.array(rewards), np.array(d_mins), np.array(vels)
    records = []
    for k, seed in enumerate(seeds):
        steps = int(world.steps[k])
        trace = Trace(
            robot_pos=np.array([p[k] for p in robot_pos[: steps + 1]]),
            robot_vel=vel_arr[:steps, k],
            robot_goal=world.robot_goal[k].copy(),
            robot_radius=config.robot_radius,
            human_pos=np.array([p[k] for p in human_pos[: steps + 1]]),
            human_goal=world.human_goal[k].copy(),
            human_radius=world.human_radius[k].copy(),
            scores=None,
            dt=config.dt,
            human_vel=np.array([v[k] for v in human_vel[: steps + 1]]),
            human_present=np.array([m[k] for m in present[: steps + 1]]),
            d_min=d_min_arr[:steps, k],
        )
        if record_traces:
            trace.actions = np.array([a[k] for a in actions[:steps]])
            if scores[0] is not None:
                trace.scores = np.array([s[k] for s in scores[:steps]])
        records.append(
            episode_record(
                seed,
                OUTCOME_NAMES[int(outcome[k])],
                rewards_arr[:steps, k],
                d_min_arr[:steps, k],
                vel_arr[:steps, k],
                world.start_dist[k],
                config,
                trace,
                keep_trace=record_traces,
            )
        )
    return records


def episode_record(
    seed: int,
    outcome: str,
    rewards: np.ndarray,
    d_min: np.ndarray,
    robot_vel: np.ndarray,
    start_dist: float,
    config: WorldConfig,
    trace: Trace | None = None,
    keep_trace: bool = True,
) -> EpisodeRecord:
    """Reduce one episode's per-step arrays to its record.

    The social metrics need ``trace`` with human velocities (nan without); the record keeps the
    trace unless ``keep_trace`` is False.
    """
    steps = len(rewards)
    t = np.arange(steps)
    discount = REPORT_GAMMA ** (t * config.dt * config.robot_v_pref)
    discomfort = (d_min > 0) & (d_min < config.discomfort_dist)
    path_length = float(np.hypot(robot_vel[:, 0], robot_vel[:, 1]).sum() * config.dt)
    success = outcome == "goal"
    spl = float(start_dist / max(path_length, start_dist)) if success else 0.0
    social = {} if trace is None or trace.human_vel is None else episode_metrics(trace)
    return EpisodeRecord(
        seed=int(seed),
        outcome=outcome,
        steps=steps,
        time=steps * config.dt,
        discounted_return=float((discount * rewards).sum()),
        total_reward=float(rewards.sum()),
        path_length=path_length,
        spl=spl,
        min_distance=float(np.min(d_min)) if d_min.size else math.inf,
        discomfort_steps=int(discomfort.sum()),
        discomfort_distance_sum=float(d_min[discomfort].sum()),
        jerk=linear_jerk(robot_vel, config.dt),
        **social,
        trace=trace if keep_trace else None,
    )


# ---------------------------------------------------------------------- metrics
def wilson_interval(successes: int, n: int) -> list[float]:
    """95% Wilson score interval of a proportion."""
    if n == 0:
        return [math.nan, math.nan]
    p = successes / n
    denom = 1 + Z95**2 / n
    centre = (p + Z95**2 / (2 * n)) / denom
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n**2)) / denom
    return [max(0.0, centre - half), min(1.0, centre + half)]


def mean_interval(
    values: np.ndarray, bounds: tuple[float, float] = (-math.inf, math.inf)
) -> tuple[float, list[float] | None]:
    """Mean and its 95% normal-approximation interval, clipped to the metric's ``bounds``.

    The mean is nan without values; the interval is None with fewer than two (no spread to
    estimate it from).
    """
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return math.nan, None
    mean = float(values.mean())
    if values.size == 1:
        return mean, None
    half = Z95 * float(values.std(ddof=1)) / math.sqrt(values.size)
    return mean, [max(bounds[0], mean - half), min(bounds[1], mean + half)]


def summarize(records: list[EpisodeRecord], config: WorldConfig | None = None) -> dict[str, dict]:
    """Every metric as {"value": v, "ci95": [lo, hi]} (definitions: docs/metrics.md).

    A metric without samples has value nan (null in JSON, "n/a" in tables) and ci95 None; a mean
    over one sample has ci95 None. Intervals stay within the metric's range; ``config`` (the world
    evaluated) adds the bounds that depend on it: time limit and discomfort distance.
    """
    time_limit = config.time_limit if config else math.inf
    discomfort_dist = config.discomfort_dist if config else math.inf
    n = len(records)
    outcomes = [r.outcome for r in records]
    counts = {name: outcomes.count(name) for name in ("goal", "collision", "timeout")}
    successes = [r for r in records if r.outcome == "goal"]
    total_steps = sum(r.steps for r in records)
    discomfort_steps = sum(r.discomfort_steps for r in records)

    def rate(k: int, total: int) -> dict:
        if not total:
            return {"value": math.nan, "ci95": None}
        return {"value": k / total, "ci95": wilson_interval(k, total)}

    def mean(values, lo: float = -math.inf, hi: float = math.inf) -> dict:
        value, ci = mean_interval(np.asarray(values, dtype=float), (lo, hi))
        return {"value": value, "ci95": ci}

    # Mean distance pools the discomfort steps of all episodes; its CI treats steps as samples.
    discomfort_d = (
        np.concatenate(
            [
                np.full(r.discomfort_steps, r.discomfort_distance_sum / r.discomfort_steps)
                for r in records
                if r.discomfort_steps
            ]
        )
        if discomfort_steps
        else np.array([])
    )
    summary = {
        "episodes": {"value": n, "ci95": None},
        "success_rate": rate(counts["goal"], n),
        "collision_rate": rate(counts["collision"], n),
        "timeout_rate": rate(counts["timeout"], n),
        "time_to_goal": mean([r.time for r in successes], 0.0, time_limit),
        "mean_distance": {
            "value": (sum(r.discomfort_distance_sum for r in records) / discomfort_steps)
            if discomfort_steps
            else math.nan,
            "ci95": mean_interval(discomfort_d, (0.0, discomfort_dist))[1],
        },
        "discomfort_frequency": rate(discomfort_steps, total_steps),
        "mean_reward": mean([r.discounted_return for r in records]),
        "path_length": mean([r.path_length for r in successes], 0.0),
        "spl": mean([r.spl for r in records], 0.0, 1.0),
        "min_distance": mean([r.min_distance for r in records if math.isfinite(r.min_distance)]),
        "jerk": mean([r.jerk for r in records], 0.0),
        "path_irregularity": mean(_known(records, "path_irregularity"), 0.0, math.pi),
        "angular_jerk": mean(_known(records, "angular_jerk"), 0.0),
        "personal_space_intrusion": mean(_known(records, "personal_space_intrusion"), 0.0, 1.0),
        "min_ttc": mean(_known(records, "min_ttc"), 0.0),
        "mean_human_distance": mean(_known(records, "mean_human_distance")),
    }
    return summary


def _known(records: list[EpisodeRecord], key: str) -> list[float]:
    """The finite values of one per-episode metric (unknown and infinite ones left out)."""
    return [v for r in records if math.isfinite(v := getattr(r, key))]


METRIC_ROWS = [
    ("success_rate", "success"),
    ("collision_rate", "collision"),
    ("timeout_rate", "timeout"),
    ("time_to_goal", "time to goal (s)"),
    ("mean_distance", "mean distance (m)"),
    ("discomfort_frequency", "discomfort freq."),
    ("mean_reward", "mean reward"),
    ("path_length", "path length (m)"),
    ("spl", "SPL"),
    ("jerk", "jerk (m/s^3)"),
    ("angular_jerk", "ang. jerk (rad/s^3)"),
    ("path_irregularity", "path irreg. (rad)"),
    ("personal_space_intrusion", "personal space intr."),
    ("min_ttc", "min TTC (s)"),
    ("mean_human_distance", "mean human gap (m)"),
]


MISSING = "n/a"  # how tables print a metric without samples (null in JSON)


def format_value(value: float | None, digits: int = 3) -> str:
    """A metric value with ``digits`` decimals; "n/a" when missing (None or nan)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return MISSING
    return f"{value:.{digits}f}"


def format_interval(ci: list | None, digits: int = 3) -> str:
    """ "[lo, hi]", or "" when the metric has no interval (missing, or a single sample)."""
    if not ci or ci[0] is None or math.isnan(ci[0]):
        return ""
    return f"[{format_value(ci[0], digits)}, {format_value(ci[1], digits)}]"


def format_table(summary: dict[str, dict], title: str = "") -> str:
    """Plain-text metrics table with 95% intervals."""
    lines = [title] if title else []
    lines.append(f"{'metric':<20} {'value':>8}   95% CI")
    for key, label in METRIC_ROWS:
        entry = summary[key]
        row = f"{label:<20} {format_value(entry['value']):>8}   {format_interval(entry['ci95'])}"
        lines.append(row.rstrip())
    return "\n".join(lines)


def write_results(
    out_dir: str | Path, summary: dict, records: list[EpisodeRecord], meta: dict
) -> None:
    """Write ``summary.json`` (metrics + run metadata) and ``episodes.jsonl`` atomically."""
    out = Path(out_dir)
    write_jsonl(out / "episodes.jsonl", (r.to_json() for r in records))
    write_json(out / "summary.json", {**summary, "meta": meta})
