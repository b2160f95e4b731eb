"""Gymnasium API: registration, spaces, check_env, info keys, native vector env."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import crowdplan  # noqa: F401  (registers the environments)
from crowdplan.sim.env import CrowdNavEnv, CrowdNavVectorEnv


@pytest.mark.parametrize("env_id", ["crowdplan/CircleCrossing-v0", "crowdplan/SquareCrossing-v0"])
def test_registered_and_check_env(env_id):
    env = gym.make(env_id, humans=3)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=1000)
    assert (
        obs["robot"].shape == (9,) and obs["humans"].shape == (3, 5) and obs["mask"].shape == (3,)
    )
    assert env.action_space == gym.spaces.Discrete(81)


def test_options_pass_through_and_padding():
    env = gym.make(
        "crowdplan/CircleCrossing-v0",
        humans=2,
        max_humans=6,
        visible_robot=True,
        kinematics="unicycle",
        speed_sampling="exponential",
    )
    obs, _ = env.reset(seed=0)
    assert obs["humans"].shape == (6, 5)
    assert obs["mask"].tolist() == [1, 1, 0, 0, 0, 0]
    assert env.unwrapped.config.visible_robot


def test_unknown_option_is_named():
    with pytest.raises(ValueError, match="unknown key"):
        gym.make("crowdplan/CircleCrossing-v0", colour="red")


def test_episode_outcome_and_d_min_info():
    env = CrowdNavEnv(humans=5)
    obs, info = env.reset(seed=1000)
    assert info["seed"] == 1000
    done, steps = False, 0
    while not done:
        obs, reward, terminated, truncated, info = env.step(0)
        assert "d_min" in info
        done = terminated or truncated
        steps += 1
    assert info["outcome"] in ("goal", "collision", "timeout")
    assert steps <= 100


def test_reset_seed_reproduces_test_case():
    env = CrowdNavEnv(humans=5)
    first = env.reset(seed=1007)[0]["humans"]
    env.step(3)
    again = env.reset(seed=1007)[0]["humans"]
    np.testing.assert_array_equal(first, again)


def test_invalid_action_rejected():
    env = CrowdNavEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="0..80"):
        env.step(81)


def test_vector_env_autoreset_same_step():
    venv = CrowdNavVectorEnv(4, humans=3)
    obs, info = venv.reset(seed=2000)
    assert info["seed"].tolist() == [2000, 2001, 2002, 2003]
    assert obs["humans"].shape == (4, 3, 5)
    saw_final = False
    for _ in range(120):  # every episode ends within 100 steps
        obs, reward, terminated, truncated, info = venv.step(np.zeros(4, dtype=np.int64))
        if "final_obs" in info:
            saw_final = True
            done = info["_final_obs"]
            assert np.all(terminated[done] | truncated[done])
            # the reset environment starts its next episode at the start position
            np.testing.assert_allclose(obs["robot"][done, :2], [[0.0, -4.0]] * done.sum())
    assert saw_final
    assert venv.next_seed > 2004


def test_zero_humans():
    env = CrowdNavEnv(humans=0)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=1000)
    assert obs["humans"].shape == (0, 5)
    _, _, _, _, info = env.step(1)
    assert info["d_min"] == float("inf")
