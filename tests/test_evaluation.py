"""Metric definitions and the batched harness."""

import math

import numpy as np
import pytest

from crowdplan import evaluation
from crowdplan.algos.orca_planner import OrcaPlanner
from crowdplan.config import WorldConfig
from crowdplan.evaluation import (
    episode_record,
    run_episodes,
    summarize,
    wilson_interval,
)


def _record(outcome, rewards, d_min, speed=1.0):
    steps = len(rewards)
    vel = np.tile([0.0, speed], (steps, 1))
    return episode_record(0, outcome, np.array(rewards), np.array(d_min), vel, 8.0, WorldConfig())


def test_episode_record_by_hand():
    rec = _record("goal", [0.0, -0.05, 1.0], [0.5, 0.1, 0.3])
    # discount 0.95^(t * 0.25 * 1)
    assert rec.discounted_return == pytest.approx(-0.05 * 0.95**0.25 + 0.95**0.5)
    assert rec.discomfort_steps == 1 and rec.discomfort_distance_sum == pytest.approx(0.1)
    assert rec.time == 0.75 and rec.path_length == pytest.approx(0.75)
    assert rec.min_distance == pytest.approx(0.1)


def test_summary_by_hand():
    records = [
        _record("goal", [0.0, 1.0], [0.5, 0.5]),
        _record("goal", [0.0, 0.0, 1.0], [0.1, 0.5, 0.5]),
        _record("collision", [-0.25], [-0.1]),
        _record("timeout", [0.0, 0.2], [0.15, 1.0]),
    ]
    s = summarize(records)
    assert s["success_rate"]["value"] == 0.5
    assert s["collision_rate"]["value"] == 0.25 and s["timeout_rate"]["value"] == 0.25
    total = s["success_rate"]["value"] + s["collision_rate"]["value"] + s["timeout_rate"]["value"]
    assert total == pytest.approx(1.0)
    assert s["time_to_goal"]["value"] == pytest.approx((0.5 + 0.75) / 2)
    assert s["mean_distance"]["value"] == pytest.approx((0.1 + 0.15) / 2)
    assert s["discomfort_frequency"]["value"] == pytest.approx(2 / 8)
    lo, hi = s["success_rate"]["ci95"]
    assert lo < 0.5 < hi


def test_wilson_interval_known_value():
    lo, hi = wilson_interval(50, 100)
    assert lo == pytest.approx(0.4038, abs=1e-4) and hi == pytest.approx(0.5962, abs=1e-4)
    assert all(math.isnan(x) for x in wilson_interval(0, 0))


def test_harness_is_deterministic_and_batch_independent():
    cfg = WorldConfig(humans=5)
    seeds = evaluation.test_seeds(12)
    a = run_episodes(OrcaPlanner(), cfg, seeds, batch_size=12)
    b = run_episodes(OrcaPlanner(), cfg, seeds, batch_size=5)
    assert [r.to_json() for r in a] == [r.to_json() for r in b]
    assert [r.seed for r in a] == seeds


def test_traces_match_records():
    (rec,) = run_episodes(OrcaPlanner(), WorldConfig(humans=3), [1000], record_traces=True)
    assert rec.trace.robot_pos.shape == (rec.steps + 1, 2)
    assert rec.trace.human_pos.shape == (rec.steps + 1, 3, 2)
    np.testing.assert_allclose(rec.trace.robot_pos[0], [0.0, -4.0])


def test_result_files_are_readable_by_others(tmp_path):
    from crowdplan.io import write_json

    write_json(tmp_path / "x.json", {"a": float("nan")})
    assert (tmp_path / "x.json").stat().st_mode & 0o044
    assert (tmp_path / "x.json").read_text().strip().endswith("}")
    assert "null" in (tmp_path / "x.json").read_text()
