"""gymnasium.make_vec gives crowdplan's native batched vector env, stepping as the class does."""

import gymnasium as gym
import numpy as np

import crowdplan  # noqa: F401  (registers the environments)
from crowdplan.sim.env import CrowdNavVectorEnv
from crowdplan.sim.world import OUTCOME_NAMES


def test_make_vec_returns_the_native_vector_env():
    env = gym.make_vec("crowdplan/CircleCrossing-v0", num_envs=64)
    assert type(env) is CrowdNavVectorEnv and env.num_envs == 64
    square = gym.make_vec("crowdplan/SquareCrossing-v0", num_envs=3, humans=2)
    assert square.config.scenario == "square_crossing" and square.config.humans == 2


def test_make_vec_steps_like_the_class_with_outcome_names():
    made = gym.make_vec("crowdplan/CircleCrossing-v0", num_envs=4, humans=3)
    direct = CrowdNavVectorEnv(4, "circle_crossing", 3)
    rng = np.random.default_rng(0)
    made.reset(seed=1000), direct.reset(seed=1000)
    seen = set()
    for _ in range(110):  # past the 100-step time limit
        actions = rng.integers(0, 81, 4)
        a, b = made.step(actions), direct.step(actions)
        for key in ("robot", "humans", "mask"):
            np.testing.assert_array_equal(a[0][key], b[0][key])
        np.testing.assert_array_equal(a[1], b[1])
        np.testing.assert_array_equal(a[4]["outcome"], b[4]["outcome"])
        seen.update(a[4]["outcome"].tolist())
    assert seen <= set(OUTCOME_NAMES.values()) and len(seen) > 1
