"""Fine-tuning DSAC from a model: the actor warm-up, init_model checks, and the conversion of
world-frame models to goal-frame actions."""

import numpy as np
import pytest
import torch

from crowdplan.algos.action_frames import world_to_goal_frame
from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.models import load_dsac_payload, load_payload, resolve_model_path
from crowdplan.nets.encoders import EncoderConfig
from crowdplan.sim.actions import action_velocities
from crowdplan.training import Trainer, config_from_dict
from tests.test_dsac import chain_mdp


def test_actor_and_temperature_stay_frozen_during_warmup():
    agent = DSAC(DSACConfig(actor_warmup_updates=2), EncoderConfig(name="aw"), seed=0)
    batch, _, _ = chain_mdp()
    initial = [p.detach().clone() for p in agent.actor.parameters()]
    critic = [p.detach().clone() for p in agent.critic.parameters()]
    alpha = agent.alpha
    for _ in range(2):
        agent.update(batch)
    assert all(torch.equal(a, b) for a, b in zip(initial, agent.actor.parameters(), strict=True))
    assert agent.alpha == alpha
    assert not all(
        torch.equal(a, b) for a, b in zip(critic, agent.critic.parameters(), strict=True)
    )
    agent.update(batch)
    assert not all(
        torch.equal(a, b) for a, b in zip(initial, agent.actor.parameters(), strict=True)
    )


def _random_states(rng, n, humans=3):
    robot = np.zeros((n, 9))
    robot[:, 0] = rng.uniform(-3, 3, n)
    robot[:, 1] = rng.uniform(-4, 0, n)
    robot[:, 2:4] = rng.uniform(-1, 1, (n, 2))
    robot[:, 4], robot[:, 7], robot[:, 8] = 0.3, 1.0, np.pi / 2
    robot[:, 5] = robot[:, 0]  # goal straight along +y: where the conversion is exact
    robot[:, 6] = robot[:, 1] + rng.uniform(1, 8, n)
    people = np.concatenate(
        [rng.uniform(-4, 4, (n, humans, 2)), rng.uniform(-1, 1, (n, humans, 2))], axis=2
    )
    people = np.concatenate([people, np.full((n, humans, 1), 0.3)], axis=2)
    return robot, people, np.ones((n, humans), dtype=bool)


def test_goal_frame_conversion_moves_the_robot_the_same_way():
    path = resolve_model_path("lsa-dsac-paper")  # trained with world-frame actions, goals along +y
    payload = load_payload(path)
    world_policy, _ = load_dsac_payload(payload, path)
    goal_policy, world = load_dsac_payload(world_to_goal_frame(payload), path)
    assert world.action_frame == "goal"
    robot, humans, mask = _random_states(np.random.default_rng(0), 64)
    before = world_policy.act(robot, humans, mask).actions
    after = goal_policy.act(robot, humans, mask).actions
    v_world, _ = action_velocities(before, robot, action_frame="world")
    v_goal, _ = action_velocities(after, robot, action_frame="goal")
    np.testing.assert_allclose(v_goal, v_world, atol=1e-12)


def test_conversion_refuses_goal_frame_models():
    payload = world_to_goal_frame(load_payload(resolve_model_path("lsa-dsac-paper")))
    with pytest.raises(ValueError, match="already acts in the goal frame"):
        world_to_goal_frame(payload)


TINY = {
    "name": "tiny",
    "episodes": 1,
    "num_envs": 1,
    "test_episodes": 0,
    "world": {"humans": 5, "time_limit": 1.0},
    "encoder": {"name": "lsa"},
}


def test_init_model_loads_the_policy_and_checks_the_action_frame(tmp_path):
    config = config_from_dict({**TINY, "dsac": {"init_model": "lsa-dsac-paper-goal"}})
    trainer = Trainer(config, tmp_path / "run", progress=False)
    expected = load_payload(resolve_model_path("lsa-dsac-paper-goal"))["actor"]
    for key, value in trainer.agent.core.actor.state_dict().items():
        assert torch.equal(value, expected[key])
    world_frame = {**TINY, "world": {**TINY["world"], "action_frame": "world"}}
    config = config_from_dict({**world_frame, "dsac": {"init_model": "lsa-dsac-paper-goal"}})
    with pytest.raises(ValueError, match="acts in the goal frame, the run in the world frame"):
        Trainer(config, tmp_path / "other", progress=False)


def test_anchor_is_the_initial_models_policy_while_the_actor_learns(tmp_path):
    dsac = {"init_model": "lsa-dsac-paper-goal", "anchor_weight": 0.01}
    dsac |= {"random_steps": 2, "learning_starts": 2}
    trainer = Trainer(config_from_dict({**TINY, "dsac": dsac}), tmp_path / "run", progress=False)
    expected = load_payload(resolve_model_path("lsa-dsac-paper-goal"))["actor"]
    trainer.run()
    core = trainer.agent.core
    assert core.n_updates > 0
    for key, value in core.anchor.state_dict().items():
        assert torch.equal(value, expected[key])
    assert not all(
        torch.equal(value, expected[key]) for key, value in core.actor.state_dict().items()
    )


def test_init_networks_continues_a_run_from_its_checkpoint_or_networks_file(tmp_path):
    from crowdplan.algos.dsac_networks import NETWORK_KEYS, main

    tiny = {**TINY, "dsac": {"random_steps": 2, "learning_starts": 2}}
    first = Trainer(config_from_dict(tiny), tmp_path / "first", progress=False)
    first.run()
    saved = torch.load(tmp_path / "first" / "checkpoint.pt", weights_only=False)
    expected = saved["agent"]["dsac"]
    assert main([str(tmp_path / "first" / "checkpoint.pt"), str(tmp_path / "networks.pt")]) == 0
    for source in (tmp_path / "first", tmp_path / "networks.pt"):
        config = config_from_dict({**TINY, "dsac": {"init_networks": str(source)}})
        core = Trainer(config, tmp_path / f"from-{source.name}", progress=False).agent.core
        for key in NETWORK_KEYS[:3]:
            for name, value in getattr(core, key).state_dict().items():
                assert torch.equal(value, expected[key][name])
        assert torch.equal(core.log_alpha.detach(), expected["log_alpha"])
    # with init_model too, the critics and temperature are the run's, the actor the model's
    both = {"init_networks": str(tmp_path / "first"), "init_model": "lsa-dsac-paper-goal"}
    trainer = Trainer(config_from_dict({**TINY, "dsac": both}), tmp_path / "both", progress=False)
    core = trainer.agent.core
    actor = load_payload(resolve_model_path("lsa-dsac-paper-goal"))["actor"]
    for name, value in core.actor.state_dict().items():
        assert torch.equal(value, actor[name])
    for name, value in core.critic.state_dict().items():
        assert torch.equal(value, expected["critic"][name])
    assert torch.equal(core.log_alpha.detach(), expected["log_alpha"])


def test_init_networks_and_the_networks_command_refuse_wrong_input(tmp_path, capsys):
    from crowdplan.algos.dsac_networks import main

    tiny = {**TINY, "dsac": {"random_steps": 2, "learning_starts": 2}}
    Trainer(config_from_dict(tiny), tmp_path / "first", progress=False).run()
    for source, error in (("nothing.pt", "does not exist"), ("best_model.pt", "not a crowdplan")):
        with pytest.raises(SystemExit):
            main([str(tmp_path / "first" / source), str(tmp_path / "networks.pt")])
        assert error in capsys.readouterr().err
    assert not (tmp_path / "networks.pt").exists()
    other = {**TINY, "encoder": {"name": "rg"}, "dsac": {"init_networks": str(tmp_path / "first")}}
    with pytest.raises(ValueError, match="has encoder"):
        Trainer(config_from_dict(other), tmp_path / "other", progress=False)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        missing = {**TINY, "dsac": {"init_networks": str(tmp_path / "nothing.pt")}}
        Trainer(config_from_dict(missing), tmp_path / "missing", progress=False)
