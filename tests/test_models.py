"""Model files: round trip, and clear errors for damaged or mismatched files."""

import numpy as np
import pytest
import torch

from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.config import WorldConfig
from crowdplan.evaluation import run_episodes, validation_seeds
from crowdplan.models import load_model_policy, model_payload
from crowdplan.nets.encoders import EncoderConfig


def _save(path, encoder="lsa"):
    agent = DSAC(DSACConfig(), EncoderConfig(name=encoder), seed=0)
    payload = model_payload(
        agent.actor, EncoderConfig(name=encoder), DSACConfig(), WorldConfig(), {}
    )
    torch.save(payload, path)
    return agent


def test_round_trip_gives_the_same_greedy_actions(tmp_path):
    agent = _save(tmp_path / "m.pt")
    policy, world = load_model_policy(str(tmp_path / "m.pt"))
    assert world == WorldConfig()
    rng = np.random.default_rng(0)
    robot = np.tile([0.0, -4.0, 0.0, 0.0, 0.3, 0.0, 4.0, 1.0, np.pi / 2], (4, 1))
    humans = np.concatenate([rng.uniform(-4, 4, (4, 5, 4)), np.full((4, 5, 1), 0.3)], axis=2)
    out = policy.act(robot, humans, np.ones((4, 5), bool))
    assert out.actions.shape == (4,) and out.scores.shape == (4, 5)
    np.testing.assert_allclose(out.scores.sum(axis=1), 1.0, rtol=1e-5)
    assert agent is not None


def test_weights_of_another_encoder_are_refused(tmp_path):
    _save(tmp_path / "m.pt", encoder="sa")
    payload = torch.load(tmp_path / "m.pt", weights_only=True)
    payload["encoder"]["name"] = "lsa"  # claims LSA but holds SA weights
    torch.save(payload, tmp_path / "m.pt")
    with pytest.raises(ValueError, match="do not match encoder 'lsa'"):
        load_model_policy(str(tmp_path / "m.pt"))


def test_corrupted_and_foreign_files(tmp_path):
    _save(tmp_path / "m.pt")
    data = (tmp_path / "m.pt").read_bytes()
    (tmp_path / "m.pt").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cannot read model file"):
        load_model_policy(str(tmp_path / "m.pt"))
    torch.save({"weights": torch.zeros(3)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a crowdplan model file"):
        load_model_policy(str(tmp_path / "other.pt"))


def test_model_for_another_action_space_is_refused(tmp_path):
    _save(tmp_path / "m.pt")
    payload = torch.load(tmp_path / "m.pt", weights_only=True)
    payload["dsac"]["n_actions"] = 17
    torch.save(payload, tmp_path / "m.pt")
    with pytest.raises(ValueError, match="trained for 17 actions"):
        load_model_policy(str(tmp_path / "m.pt"))


def test_shipped_model_loads_by_name():
    policy, world = load_model_policy("lsa-dsac-paper")
    assert world.humans == 5 and policy.metadata["encoder"] == "lsa"


def test_shipped_rg_dqn_loads_by_name_and_reaches_goals():
    policy, world = load_model_policy("rg-dqn")
    assert policy.metadata["algo"] == "dqn" and world.humans == 5
    records = run_episodes(policy, world, validation_seeds(20))
    assert sum(r.outcome == "goal" for r in records) >= 17


def test_shipped_unicycle_model_reaches_goals_within_its_turn_limit():
    policy, world = load_model_policy("lsa-dsac-unicycle")
    assert world.kinematics == "unicycle" and world.humans == 5
    records = run_episodes(policy, world, validation_seeds(20), record_traces=True)
    assert sum(r.outcome == "goal" for r in records) >= 17
    for record in records:
        vel = record.trace.robot_vel
        moving = np.linalg.norm(vel, axis=1) > 1e-6
        both = moving[1:] & moving[:-1]
        heading = np.arctan2(vel[:, 1], vel[:, 0])
        turn = np.angle(np.exp(1j * (heading[1:] - heading[:-1])))[both]
        assert np.all(np.abs(turn) <= np.pi / 4 + 1e-6)  # never more than one step's rotation
