"""Gymnasium environments: a single env and a native batched vector env over one ``World``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from crowdplan.config import WorldConfig
from crowdplan.sim.actions import N_ACTIONS
from crowdplan.sim.world import OUTCOME_NAMES, RUNNING, World

TRAIN_SEED_BASE = 2000
# outcome code -> name, for one fancy-indexing per step instead of a Python loop over envs
_OUTCOME_NAME_ARRAY = np.array([OUTCOME_NAMES[code] for code in range(max(OUTCOME_NAMES) + 1)])


def make_world_config(scenario: str, humans: int = 5, **options: Any) -> WorldConfig:
    """WorldConfig from keyword options, with a clear error for unknown option names."""
    return WorldConfig.from_dict({"scenario": scenario, "humans": humans, **options})


def observation_space(max_humans: int) -> spaces.Dict:
    """Dict space: robot (9,), humans (max_humans, 5), mask (max_humans,)."""
    return spaces.Dict(
        {
            "robot": spaces.Box(-np.inf, np.inf, (9,), np.float64),
            "humans": spaces.Box(-np.inf, np.inf, (max_humans, 5), np.float64),
            # a Box rather than MultiBinary, which cannot have zero elements (N = 0)
            "mask": spaces.Box(0, 1, (max_humans,), np.int8),
        }
    )


def pad_observation(robot, humans, mask, max_humans: int) -> dict[str, np.ndarray]:
    """Batched observation dict with humans padded (zeros, mask 0) to ``max_humans``."""
    e, n = mask.shape
    padded = np.zeros((e, max_humans, 5))
    padded[:, :n] = humans
    padded_mask = np.zeros((e, max_humans), dtype=np.int8)
    padded_mask[:, :n] = mask
    return {"robot": robot, "humans": padded, "mask": padded_mask}


class CrowdNavEnv(gym.Env):
    """Robot navigation through a crowd of ORCA-driven humans.

    ## Description
    A disc robot starts at (0, -4) and must reach (0, 4) within 25 s while N humans cross the
    scene (circle_crossing or square_crossing, SPEC.md section 1).

    ## Action Space
    ``Discrete(81)``: 0 = stop, 1 + d*5 + s = direction d (k*pi/8) at speed s ({0.2..1.0} v_pref).

    ## Observation Space
    ``Dict(robot=(9,), humans=(max_humans, 5), mask=(max_humans,))``: robot px, py, vx, vy, r,
    gx, gy, v_pref, theta; human px, py, vx, vy, r; mask 1 for real humans.

    ## Rewards
    +1 goal, -0.25 collision, -0.1 + d_min/2 for 0 < d_min < 0.2, timeout 0.5 * progress.

    ## Starting State
    ``reset(seed=1000 + k)`` is test case k, ``seed=k`` validation case k; each episode is a pure
    function of its seed. Without a seed, one is drawn from ``self.np_random``.

    ## Episode End
    Terminated on goal or collision, truncated at the time limit. ``info["outcome"]`` is "goal",
    "collision" or "timeout" on the last step; ``info["d_min"]`` is given on every step.

    ## Arguments
    ``scenario``, ``humans`` (N), ``max_humans`` (padding, default N) and every ``WorldConfig``
    option (visible_robot, randomize_attributes, respawn_on_arrival, kinematics, speed_sampling...).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        scenario: str = "circle_crossing",
        humans: int = 5,
        max_humans: int | None = None,
        render_mode: str | None = None,
        **options: Any,
    ) -> None:
        self.config = make_world_config(scenario, humans, **options)
        self.max_humans = humans if max_humans is None else max_humans
        if self.max_humans < humans:
            raise ValueError(f"max_humans ({max_humans}) must be >= humans ({humans})")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.world = World(self.config, 1)
        self.observation_space = observation_space(self.max_humans)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self._history: list[tuple[np.ndarray, np.ndarray]] = []

    def _obs(self) -> dict[str, np.ndarray]:
        batch = pad_observation(*self.world.observe(), self.max_humans)
        return {key: value[0] for key, value in batch.items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        episode_seed = seed if seed is not None else int(self.np_random.integers(2**31 - 1))
        self.world.reset([episode_seed])
        self._history = [(self.world.robot_pos[0].copy(), self.world.human_pos[0].copy())]
        return self._obs(), {"seed": int(episode_seed)}

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is outside the valid range 0..{N_ACTIONS - 1}")
        result = self.world.step(np.array([int(action)]))
        self._history.append((self.world.robot_pos[0].copy(), self.world.human_pos[0].copy()))
        info: dict[str, Any] = {"d_min": float(result.d_min[0])}
        if result.outcome[0] != RUNNING:
            info["outcome"] = OUTCOME_NAMES[int(result.outcome[0])]
        return (
            self._obs(),
            float(result.reward[0]),
            bool(result.terminated[0]),
            bool(result.truncated[0]),
            info,
        )

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from crowdplan.sim.render import scene_rgb

        return scene_rgb(self.world, 0, self._history)


class CrowdNavVectorEnv(VectorEnv):
    """E environments in one process over one batched ``World`` (autoreset in the same step).

    When an episode ends its environment is reset at once with the next episode seed;
    the true last observation is in ``info["final_obs"]`` (mask ``info["_final_obs"]``).
    ``reset(seed=S)`` numbers episodes S, S+1, ... in the order they start (default 2000, the
    training seeds).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int,
        scenario: str = "circle_crossing",
        humans: int = 5,
        max_humans: int | None = None,
        **options: Any,
    ) -> None:
        self.config = make_world_config(scenario, humans, **options)
        self.num_envs = num_envs
        self.max_humans = humans if max_humans is None else max_humans
        self.world = World(self.config, num_envs)
        self.single_observation_space = observation_space(self.max_humans)
        self.single_action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.next_seed = TRAIN_SEED_BASE

    def observe(self) -> dict[str, np.ndarray]:
        return pad_observation(*self.world.observe(), self.max_humans)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.next_seed = int(seed)
        seeds = np.arange(self.next_seed, self.next_seed + self.num_envs)
        self.next_seed += self.num_envs
        self.world.reset(seeds)
        return self.observe(), {"seed": seeds}

    def step(self, actions):
        result = self.world.step(np.asarray(actions, dtype=np.int64))
        done = result.terminated | result.truncated
        info: dict[str, Any] = {
            "d_min": result.d_min,
            "outcome": _OUTCOME_NAME_ARRAY[result.outcome],
            "seed": self.world.seeds.copy(),
        }
        if done.any():
            final = self.observe()
            info["final_obs"] = final
            info["_final_obs"] = done
            ids = np.flatnonzero(done)
            self.world.reset(np.arange(self.next_seed, self.next_seed + len(ids)), ids)
            self.next_seed += len(ids)
        return self.observe(), result.reward, result.terminated, result.truncated, info
