"""RG-DQN (double DQN): target maths, exploration schedule, determinism, resume, CLI, bad input."""

import dataclasses

import pytest
import torch
import yaml
from tiny_runs import flat_parameters, restored, train_tiny

from crowdplan.algos.dqn import DQNPolicy, double_dqn_target, load_dqn_payload
from crowdplan.cli import main
from crowdplan.models import load_model_policy
from crowdplan.training import config_from_dict, load_config

TINY = {
    "name": "tiny_dqn",
    "algo": "dqn",
    "episodes": 6,
    "num_envs": 2,
    "val_interval": 1000,
    "val_episodes": 2,
    "checkpoint_interval": 1000,
    "log_interval": 1000,
    "test_episodes": 0,
    "world": {"humans": 3, "time_limit": 4.0},
    "encoder": {"name": "rg"},
    "dqn": {"batch_size": 16, "learning_starts": 16, "target_update": 5, "epsilon_episodes": 4},
}


def _weights(trainer):
    return flat_parameters(trainer.agent.q)


def test_double_dqn_target_on_known_numbers():
    reward = torch.tensor([1.0, 0.5, -0.25])
    done = torch.tensor([0.0, 0.0, 1.0])
    online = torch.tensor([[0.0, 2.0, 1.0], [5.0, 0.0, 1.0], [9.0, 9.0, 9.0]])
    target = torch.tensor([[7.0, 3.0, 100.0], [4.0, 8.0, 1.0], [9.0, 9.0, 9.0]])
    # the online network picks a' (1, then 0); the target network values it; done cuts it off
    expected = torch.tensor([1.0 + 0.5 * 3.0, 0.5 + 0.5 * 4.0, -0.25])
    assert torch.equal(double_dqn_target(reward, done, online, target, 0.5), expected)
    # clip_q_targets: an overestimated bootstrap is held to the reachable returns
    clipped = double_dqn_target(reward, done, online, target, 0.5, bounds=(-0.2, 2.0))
    assert torch.equal(clipped, torch.tensor([2.0, 2.0, -0.2]))


def test_epsilon_falls_linearly_over_episodes(tmp_path):
    trainer = train_tiny(TINY, tmp_path, "eps", episodes=2)
    agent = trainer.agent
    agent.episodes_done(2)
    assert agent.epsilon == pytest.approx(1.0 + 0.5 * (0.05 - 1.0))
    agent.episodes_done(40)
    assert agent.epsilon == pytest.approx(0.05)


def test_same_seed_twice_is_identical_and_resume_continues_exactly(tmp_path):
    a, b = train_tiny(TINY, tmp_path, "a"), train_tiny(TINY, tmp_path, "b")
    assert a.agent.n_updates > 5 and torch.equal(_weights(a), _weights(b))
    first = train_tiny(TINY, tmp_path, "resumed", episodes=3)
    resumed = restored(dataclasses.replace(first.config, episodes=6), first.run_dir)
    resumed.run()
    assert torch.equal(_weights(a), _weights(resumed))
    assert resumed.agent.epsilon == a.agent.epsilon
    assert [e["seed"] for e in a.episodes] == [e["seed"] for e in resumed.episodes]


def test_polyak_target_follows_the_online_network_by_tau(tmp_path):
    data = {**TINY, "dqn": {**TINY["dqn"], "tau": 0.25}}
    trainer = train_tiny(data, tmp_path, "polyak", episodes=2)
    agent = trainer.agent
    before = flat_parameters(agent.q_target)
    batch = agent.buffer.sample(agent.params.batch_size)
    agent._learn(batch)
    after_online, after_target = flat_parameters(agent.q), flat_parameters(agent.q_target)
    assert not torch.equal(before, after_target)
    assert torch.allclose(after_target, 0.75 * before + 0.25 * after_online, atol=1e-6)


def test_train_eval_render_from_the_command_line(tmp_path):
    data = {**TINY, "episodes": 4, "val_interval": 2, "test_episodes": 2}
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--out", str(run), "--no-progress"]) == 0
    assert (
        main(["eval", "--model", str(run), "--episodes", "2", "--out", str(tmp_path / "ev")]) == 0
    )
    picture = tmp_path / "case.png"
    assert main(["render", "--model", str(run), "--case", "0", "--out", str(picture)]) == 0
    policy, _ = load_model_policy(str(run / "best_model.pt"))
    assert isinstance(policy, DQNPolicy) and policy.metadata["encoder"] == "rg"
    out = policy.act(*_observation())
    assert out.scores is not None and out.scores.shape == (1, 3)  # RG's attention


def _observation():
    from crowdplan.sim.env import CrowdNavVectorEnv

    obs, _ = CrowdNavVectorEnv(1, "circle_crossing", 3).reset(seed=5)
    return obs["robot"], obs["humans"], obs["mask"].astype(bool)


def test_preset_loads():
    config = load_config("configs/rg_dqn.yaml")
    assert config.algo == "dqn" and config.encoder.name == "rg" and config.world.humans == 5


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        ({**TINY, "a2c": {}}, "section(s) ['a2c'] belong to another algorithm"),
        ({**TINY, "dqn": {"epsilon_end": 1.5}}, "dqn.epsilon_end must be >= 0.0 and <= 1.0"),
        ({**TINY, "dqn": {"polyak": 0.1}}, "unknown key(s) ['polyak'] in dqn"),
        ({**TINY, "dqn": {"tau": 1.5}}, "dqn.tau must be >= 0.0 and <= 1.0"),
        ({**TINY, "dqn": {"return_min": 1.0, "return_max": 1.0}}, "dqn.return_min (1.0) must be"),
    ],
)
def test_bad_config_is_explained(data, fragment):
    with pytest.raises(ValueError) as error:
        config_from_dict(data)
    assert fragment in str(error.value)


def test_model_of_another_algorithm_is_refused(tmp_path):
    run = train_tiny(TINY, tmp_path, "run", episodes=2).run_dir
    payload = torch.load(run / "final_model.pt", weights_only=True)
    with pytest.raises(ValueError, match="not a DQN model"):
        load_dqn_payload({**payload, "format": "crowdplan-a2c-policy/1"}, run / "x.pt")
    wrong = tmp_path / "wrong.pt"
    torch.save({**payload, "encoder": {**payload["encoder"], "name": "lsa"}}, wrong)
    with pytest.raises(ValueError, match="do not match encoder 'lsa'"):
        load_model_policy(str(wrong))
