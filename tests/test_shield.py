"""The safety shield: clearances of hand-made scenes, the choice it makes, how model files,
the command line, the test worlds and ONNX exports carry it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from crowdplan.analysis.test_worlds import eval_arguments
from crowdplan.config import WorldConfig
from crowdplan.models import load_model_policy, load_payload, resolve_model_path
from crowdplan.planner_options import with_shield
from crowdplan.sim.actions import N_ACTIONS
from crowdplan.sim.shield import Shield

GOAL_FRAME = WorldConfig(action_frame="goal")  # holonomic, linear speeds
STOP, TO_GOAL_FULL, LEFT_FULL = 0, 1 + 0 * 5 + 4, 1 + 4 * 5 + 4  # goal-frame action indices


def scene(human_xy, human_vel=(0.0, 0.0)):
    """Robot (radius 0.3) at the origin with its goal at (10, 0); one human of radius 0.3."""
    robot = np.array([[0.0, 0.0, 0.0, 0.0, 0.3, 10.0, 0.0, 1.0, 0.0]])
    humans = np.array([[[*human_xy, *human_vel, 0.3]]])
    return robot, humans, np.ones((1, 1), dtype=bool)


def clearance(shield, robot, humans, mask):
    return shield.clearance(robot, humans, mask, GOAL_FRAME)[0]


def test_clearance_of_a_standing_human_on_the_path():
    gap = clearance(Shield(2.5), *scene((2.0, 0.0)))
    assert gap.shape == (N_ACTIONS,)
    # driving at the human at 1 m/s for 2.5 s passes through it: the paths overlap
    assert gap[TO_GOAL_FULL] == pytest.approx(-0.6)
    # standing, or driving sideways, keeps the start distance 2 m minus both radii
    assert gap[STOP] == pytest.approx(1.4)
    assert gap[LEFT_FULL] == pytest.approx(1.4)


def test_clearance_counts_a_human_walking_into_the_robot():
    # a human 3 m ahead walking at the robot at 1 m/s: within 1 s it is 2 m away, within 3 s on top
    robot, humans, mask = scene((3.0, 0.0), (-1.0, 0.0))
    assert clearance(Shield(1.0), robot, humans, mask)[STOP] == pytest.approx(2.0 - 0.6)
    assert clearance(Shield(3.0), robot, humans, mask)[STOP] == pytest.approx(-0.6)


def test_no_humans_means_every_action_is_safe():
    robot, humans, mask = scene((2.0, 0.0))
    gap = Shield(2.5).clearance(robot, humans, ~mask, GOAL_FRAME)
    assert np.isinf(gap).all()
    scores = np.random.default_rng(0).normal(size=(1, N_ACTIONS))
    assert Shield(2.5).choose(scores, gap)[0] == scores.argmax()


def test_choose_takes_the_best_safe_action_else_the_largest_clearance():
    scores = np.zeros((2, N_ACTIONS))
    scores[:, 7], scores[:, 3] = 2.0, 1.0
    gap = np.full((2, N_ACTIONS), -1.0)
    gap[0, 3] = gap[0, 9] = 0.5  # env 0: action 7 (best) unsafe, 3 and 9 safe
    gap[1, 11] = -0.1  # env 1: nothing safe; action 11 comes closest to safe
    np.testing.assert_array_equal(Shield(1.0).choose(scores, gap), [3, 11])
    # a margin makes an action that only just clears unsafe
    np.testing.assert_array_equal(Shield(1.0, margin=0.6).choose(scores, gap)[:1], [3])


@pytest.mark.parametrize("horizon", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_horizons_are_refused(horizon):
    with pytest.raises(ValueError, match="positive number of seconds"):
        Shield(horizon)


def test_shipped_planner_uses_its_shield_and_the_paper_model_none():
    policy, _ = load_model_policy("lsa-dsac")
    assert policy.shield == Shield(2.5) and policy.metadata["shield_horizon"] == 2.5
    off, _ = load_model_policy("lsa-dsac", shield=0)
    assert off.shield is None and off.metadata["shield_horizon"] is None
    paper, _ = load_model_policy("lsa-dsac-paper")
    assert paper.shield is None


def test_shield_overrides_only_the_unsafe_greedy_actions():
    shielded, _ = load_model_policy("lsa-dsac")
    plain, _ = load_model_policy("lsa-dsac", shield=0)
    rng = np.random.default_rng(3)
    robot = np.tile([0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 4.0, 1.0, np.pi / 2], (64, 1))
    humans = np.concatenate(
        [rng.uniform(-2, 2, (64, 5, 2)), rng.uniform(-1, 1, (64, 5, 2)), np.full((64, 5, 1), 0.3)],
        axis=2,
    )
    mask = np.ones((64, 5), dtype=bool)
    chosen = shielded.act(robot, humans, mask).actions
    greedy = plain.act(robot, humans, mask).actions
    gap = Shield(2.5).clearance(robot, humans, mask, GOAL_FRAME)
    rows = np.arange(64)
    kept = gap[rows, greedy] >= 0
    np.testing.assert_array_equal(chosen[kept], greedy[kept])
    has_safe = (gap >= 0).any(axis=1)
    overridden = ~kept & has_safe
    assert overridden.any() and (chosen[overridden] != greedy[overridden]).all()
    assert (gap[rows, chosen][has_safe] >= 0).all()
    # with no safe action the shield keeps the largest clearance, which may be the greedy action
    no_safe = ~has_safe
    assert no_safe.any()
    np.testing.assert_array_equal(gap[rows, chosen][no_safe], gap[no_safe].max(axis=1))


def test_shield_needs_a_model_that_ranks_actions(capsys):
    from crowdplan.cli import main

    assert main(["eval", "--policy", "orca", "--shield", "2", "--episodes", "1"]) == 2
    assert "--shield filters a trained model's action scores" in capsys.readouterr().err
    assert main(["eval", "--model", "sarl", "--shield", "2", "--episodes", "1"]) == 2
    assert "drop --shield" in capsys.readouterr().err


def test_model_file_round_trip_of_the_shield(tmp_path):
    payload = load_payload(resolve_model_path("lsa-dsac-paper-goal"))
    path = tmp_path / "model.pt"
    torch.save(with_shield(payload, 1.5), path)
    policy, _ = load_model_policy(str(path))
    assert policy.shield == Shield(1.5)
    torch.save(with_shield(with_shield(payload, 1.5), 0), path)
    assert load_model_policy(str(path))[0].shield is None


def test_test_world_planner_option():
    args = eval_arguments("lsa-dsac@shield=0", "circle", "out", 10)
    assert args[1:5] == ["--model", "lsa-dsac", "--shield", "0"]
    with pytest.raises(ValueError, match="NAME@shield=SECONDS"):
        eval_arguments("lsa-dsac@speed=2", "circle", "out", 10)


def test_onnx_export_carries_the_shield(tmp_path):
    pytest.importorskip("onnxruntime")
    from crowdplan.deploy.export import export_model, random_observations
    from crowdplan.deploy.onnx_policy import OnnxPolicy

    manifest, _ = export_model("lsa-dsac", tmp_path / "export", max_humans=10)
    assert manifest.shield_horizon == 2.5
    onnx_policy = OnnxPolicy(tmp_path / "export")
    policy, _ = load_model_policy("lsa-dsac")
    robot, humans, mask = random_observations(np.random.default_rng(1), 32, 5, 0)
    np.testing.assert_array_equal(
        onnx_policy.act(robot, humans, mask).actions, policy.act(robot, humans, mask).actions
    )


def test_world_frame_export_with_a_shield_is_refused(tmp_path):
    pytest.importorskip("onnxruntime")
    from crowdplan.deploy.export import export_model

    payload = load_payload(resolve_model_path("lsa-dsac-paper"))
    torch.save(with_shield(payload, 2.5), tmp_path / "model.pt")
    with pytest.raises(ValueError, match="world-frame actions"):
        export_model(str(tmp_path / "model.pt"), tmp_path / "export")


def test_shield_tuning_and_planner_options_entry_points(tmp_path, capsys):
    from crowdplan import planner_options
    from crowdplan.analysis import shield_tuning

    out = tmp_path / "tuning.json"
    argv = ["lsa-dsac", "--horizons", "0", "2.5", "--worlds", "circle", "--cases", "4"]
    assert shield_tuning.main([*argv, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "seeds 100..103" in printed and "| circle |" in printed
    assert set(json.loads(out.read_text())["worlds"]["circle"]) == {"0.0", "2.5"}

    model = tmp_path / "model.pt"
    model.write_bytes(resolve_model_path("lsa-dsac-paper-goal").read_bytes())
    assert planner_options.main([str(model), "--shield", "1.5"]) == 0
    assert load_model_policy(str(model))[0].shield == Shield(1.5)
