"""Simulated deployment: the runtime in a closed loop with the simulator as the mocap system.

Each test case runs one :class:`~crowdplan.sim.world.World` (its dt is the control period). At
every control step the world's true poses go through a sensor model (Gaussian position and yaw
noise, a slow random-walk drift per agent, dropped samples, a latency of whole control periods)
into a :class:`~crowdplan.deploy.runtime.Runtime`, whose robot command drives the world's robot.
The episode records and metrics are those of ``crowdplan eval`` (``crowdplan.evaluation``); with
no noise, no latency and the world's own control rate the loop reproduces ``crowdplan eval``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.deploy.onnx_policy import OnnxPolicy
from crowdplan.deploy.runtime import Agent, Runtime, RuntimeConfig
from crowdplan.evaluation import EpisodeRecord, episode_record
from crowdplan.sim.world import OUTCOME_NAMES, RUNNING, World

ROBOT_ID = "robot"


@dataclass(frozen=True)
class SensorModel:
    """What the simulated mocap system gets wrong.

    Attributes:
        position_noise: standard deviation (m) of independent Gaussian noise on x and y.
        yaw_noise: standard deviation (rad) of the yaw noise.
        drift: random-walk bias of each agent's position, standard deviation in m per sqrt(s).
        latency: delay (s) of every pose, rounded to whole control periods.
        drop_rate: probability that one agent's sample is missing from a frame.
        seed: noise of case k is drawn from the generator seeded (seed, case seed).
    """

    position_noise: float = 0.0
    yaw_noise: float = 0.0
    drift: float = 0.0
    latency: float = 0.0
    drop_rate: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("position_noise", "yaw_noise", "drift", "latency"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not 0 <= self.drop_rate < 1:
            raise ValueError(f"drop_rate must be in [0, 1), got {self.drop_rate!r}")


def deployment_world(config: WorldConfig, control_rate: float | None) -> WorldConfig:
    """The world stepped at the control rate (None: the world's own dt)."""
    if control_rate is None:
        return config
    if not control_rate > 0:
        raise ValueError(f"control rate must be > 0 Hz, got {control_rate!r}")
    return config.replace(dt=1.0 / control_rate)


def run_deployment(
    policy: OnnxPolicy,
    config: WorldConfig,
    seeds: list[int],
    sensor: SensorModel | None = None,
    runtime_config: RuntimeConfig | None = None,
) -> tuple[list[EpisodeRecord], dict[str, float]]:
    """Run one closed-loop episode per seed; returns the records and deployment statistics
    (``safety_stop_share``: share of robot steps with a safety stop)."""
    sensor = sensor or SensorModel()
    runtime_config = runtime_config or RuntimeConfig(control_rate=1.0 / config.dt)
    if not math.isclose(runtime_config.period, config.dt):
        raise ValueError(
            f"the world's dt ({config.dt} s) must be the control period "
            f"({runtime_config.period} s): build it with deployment_world()"
        )
    policy.manifest.check_world(config)
    records, stops, steps = [], 0, 0
    for seed in seeds:
        record, episode_stops = _run_episode(policy, config, seed, sensor, runtime_config)
        records.append(record)
        stops += episode_stops
        steps += record.steps
    return records, {"safety_stop_share": stops / steps if steps else math.nan}


def _run_episode(policy, config, seed, sensor, runtime_config) -> tuple[EpisodeRecord, int]:
    world = World(config, 1)
    world.reset([seed])
    n = config.humans
    human_ids = [f"human{h}" for h in range(n)]
    agents = [
        Agent(
            ROBOT_ID,
            "robot",
            config.robot_radius,
            config.robot_v_pref,
            tuple(world.robot_goal[0]),
            "holonomic" if config.kinematics == "holonomic" else "diff_drive",
        ),
        *(Agent(h, "human", float(world.human_radius[0, k])) for k, h in enumerate(human_ids)),
    ]
    runtime = Runtime(policy, agents, runtime_config)
    rng = np.random.default_rng([sensor.seed, seed])
    drift = np.zeros((n + 1, 2))
    delay = int(round(sensor.latency / config.dt))
    queue: deque = deque()
    rewards, d_mins, vels, stops = [], [], [], 0
    outcome = RUNNING
    while outcome == RUNNING:
        t = world.steps[0] * config.dt
        pos = np.concatenate([world.robot_pos, world.human_pos[0]])
        yaw = np.concatenate([world.robot_theta, np.arctan2(*world.human_vel[0].T[::-1])])
        if sensor.drift:
            drift += rng.normal(0.0, sensor.drift * math.sqrt(config.dt), drift.shape)
        if sensor.position_noise:
            pos = pos + rng.normal(0.0, sensor.position_noise, pos.shape)
        if sensor.yaw_noise:
            yaw = yaw + rng.normal(0.0, sensor.yaw_noise, yaw.shape)
        keep = rng.random(n + 1) >= sensor.drop_rate if sensor.drop_rate else np.ones(n + 1, bool)
        queue.append((t, pos + drift, yaw, keep))
        if len(queue) > delay:
            stamp, p, theta, seen = queue.popleft()
            for k, key in enumerate([ROBOT_ID, *human_ids]):
                if seen[k]:
                    runtime.pose(key, stamp, p[k, 0], p[k, 1], theta[k])
        command = runtime.step(t)[ROBOT_ID]
        stops += command.stop
        if config.kinematics == "holonomic":
            action = np.array([[command.vx, command.vy]])
        else:
            action = np.array([[command.v, command.omega * config.dt]])
        result = world.step(action)
        outcome = int(result.outcome[0])
        rewards.append(result.reward[0])
        d_mins.append(result.d_min[0])
        vels.append(world.robot_vel[0].copy())
    record = episode_record(
        seed,
        OUTCOME_NAMES[outcome],
        np.array(rewards),
        np.array(d_mins),
        np.array(vels).reshape(-1, 2),
        world.start_dist[0],
        config,
    )
    return record, stops


def sensor_dict(sensor: SensorModel) -> dict:
    """The sensor model as plain data for result files."""
    return asdict(sensor)
