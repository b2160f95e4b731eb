"""Imitation learning from ORCA demonstrations."""

import numpy as np
import pytest
import torch

from crowdplan.algos.dsac import Actor
from crowdplan.algos.imitation import (
    DEMO_SEED_BASE,
    collect_demonstrations,
    demonstration_seeds,
    fit_actions,
    fit_values,
    nearest_actions,
)
from crowdplan.algos.orca_planner import OrcaPlanner
from crowdplan.config import WorldConfig
from crowdplan.evaluation import run_episodes
from crowdplan.features import robot_centric
from crowdplan.nets.encoders import EncoderConfig, make_encoder
from crowdplan.nets.value import make_value_network
from crowdplan.sim.actions import every_action_velocity
from crowdplan.sim.world import World

GAMMA = 0.9**0.25


def test_returns_are_the_discounted_rewards_of_an_orca_episode():
    config = WorldConfig(humans=2)
    seeds = demonstration_seeds(1, run_seed=0)
    demos = collect_demonstrations(config, seeds, GAMMA)
    (record,) = run_episodes(OrcaPlanner(config.dt, config.orca, 0.15), config, seeds)
    assert len(demos) == record.steps and demos.outcomes == {record.outcome: 1}
    assert demos.rewards.sum() == pytest.approx(record.total_reward, abs=1e-5)
    t = np.arange(len(demos))
    expected = [(GAMMA ** (t[k:] - k) * demos.rewards[k:]).sum() for k in t]
    np.testing.assert_allclose(demos.returns, expected, rtol=1e-5, atol=1e-6)
    assert demos.terminated[-1] == (record.outcome != "timeout") and not demos.terminated[:-1].any()
    # s' of each step is the next row's s
    np.testing.assert_array_equal(demos.next_states.robot[:-1], demos.states.robot[1:])


def test_zero_demonstrations_is_refused():
    with pytest.raises(ValueError, match="set il_episodes: 0 to skip"):
        demonstration_seeds(0, run_seed=0)
    with pytest.raises(ValueError, match="at least one"):
        collect_demonstrations(WorldConfig(), [], GAMMA)


def test_demonstration_seeds_avoid_every_other_split():
    seeds = demonstration_seeds(3000, run_seed=2)
    assert min(seeds) >= DEMO_SEED_BASE and seeds != demonstration_seeds(3000, run_seed=0)


def test_imitation_learning_fits_orca_returns():
    config = WorldConfig(humans=2)
    demos = collect_demonstrations(config, demonstration_seeds(20, run_seed=0), GAMMA)
    torch.manual_seed(0)
    net = make_value_network("sarl")
    generator = torch.Generator().manual_seed(0)
    loss = fit_values(net, demos, epochs=40, lr=0.01, batch_size=100, generator=generator)
    spread = float(np.var(demos.returns))
    with torch.no_grad():
        values, _ = net(*(torch.from_numpy(x) for x in demos.states))
    mse = float(((values.numpy() - demos.returns) ** 2).mean())
    assert loss < 0.2 * spread and mse < 0.2 * spread


@pytest.mark.parametrize("frame", ["world", "goal"])
def test_nearest_action_of_an_action_velocity_is_that_action(frame):
    config = WorldConfig(humans=1, action_frame=frame)
    world = World(config, 3)
    world.reset([0, 1, 2])
    robot = world.observe()[0]
    velocities, _ = every_action_velocity(robot, action_frame=frame)
    picks = np.array([0, 17, 80])
    commands = velocities[np.arange(3), picks]
    np.testing.assert_array_equal(nearest_actions(commands, robot, config), picks)
    nudged = nearest_actions(commands + 0.01, robot, config)
    np.testing.assert_array_equal(nudged[1:], picks[1:])


def test_discrete_demonstrations_replay_to_the_same_transitions():
    config = WorldConfig(humans=3, action_frame="goal")
    seeds = demonstration_seeds(1, run_seed=0)
    demos = collect_demonstrations(config, seeds, GAMMA, discrete=True)
    assert demos.actions is not None and len(demos.actions) == len(demos)
    world = World(config, 1)
    world.reset(seeds)
    rewards = [world.step(demos.actions[t : t + 1]).reward[0] for t in range(len(demos))]
    np.testing.assert_allclose(rewards, demos.rewards, atol=1e-6)
    final = robot_centric(*world.observe())
    np.testing.assert_allclose(final.robot[0], demos.next_states.robot[-1], atol=1e-5)


def test_behaviour_cloning_learns_the_demonstrated_actions():
    config = WorldConfig(humans=2)
    demos = collect_demonstrations(config, demonstration_seeds(10, 0), GAMMA, discrete=True)
    torch.manual_seed(0)
    actor = Actor(make_encoder(EncoderConfig(name="sa")), 81, (64,), detach_encoder=False)
    generator = torch.Generator().manual_seed(0)
    first = fit_actions(actor, demos, epochs=1, lr=1e-3, batch_size=64, generator=generator)
    last = fit_actions(actor, demos, epochs=30, lr=1e-3, batch_size=64, generator=generator)
    assert last["bc_loss"] < 0.5 * first["bc_loss"] and last["bc_accuracy"] > 0.5  # chance: 1/81
    with pytest.raises(ValueError, match="discrete demonstrations"):
        fit_actions(actor, collect_demonstrations(config, [5], GAMMA), 1, 1e-3, 64, generator)
