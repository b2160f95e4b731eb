"""The fused Numba step kernel of ``World`` against a plain numpy statement of the same step."""

import copy
import hashlib
from pathlib import Path

import numpy as np
import pytest

from crowdplan.config import WorldConfig
from crowdplan.sim import orca
from crowdplan.sim.actions import action_velocities
from crowdplan.sim.orca import orca_velocities, preferred_velocities
from crowdplan.sim.world import (
    COLLISION,
    GOAL,
    RUNNING,
    TIMEOUT,
    StepResult,
    World,
    compute_reward,
    point_to_segment_distance,
)

STATE = ("robot_pos", "robot_vel", "robot_theta", "human_pos", "human_vel", "human_goal", "steps")
ATOL = 1e-12


def reference_step(world: World, actions: np.ndarray, active: np.ndarray | None) -> StepResult:
    """``World.step`` written with numpy array operations (the implementation before the kernel)."""
    cfg = world.config
    e, n = world.num_envs, cfg.humans
    active = np.ones(e, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    unicycle = cfg.kinematics == "unicycle"

    # Robot velocity and heading.
    actions = np.asarray(actions)
    if actions.dtype.kind in "iu":
        robot = world.observe()[0]
        robot_vel, theta = action_velocities(
            np.broadcast_to(actions, (e,)),
            robot,
            cfg.kinematics,
            cfg.action_frame,
            cfg.speed_sampling,
        )
    else:
        if unicycle:
            speed_angle = actions
        else:
            speed = np.minimum(np.hypot(actions[:, 0], actions[:, 1]), cfg.robot_v_pref)
            speed_angle = np.stack([speed, np.arctan2(actions[:, 1], actions[:, 0])], axis=1)
        speed, angle = speed_angle[:, 0], speed_angle[:, 1]
        theta = world.robot_theta + angle if unicycle else world.robot_theta
        heading = theta if unicycle else angle
        robot_vel = np.stack([speed * np.cos(heading), speed * np.sin(heading)], axis=1)

    # Humans: one ORCA solve per environment; a visible robot is agent 0, never solved.
    pos, vel = world.human_pos, world.human_vel
    radii, speeds = world.human_radius, world.human_v_pref
    pref = preferred_velocities(world.human_pos, world.human_goal, world.human_v_pref)
    solve = np.repeat(active[:, None], n, axis=1)
    if cfg.visible_robot:
        pos = np.concatenate([world.robot_pos[:, None], pos], axis=1)
        vel = np.concatenate([world.robot_vel[:, None], vel], axis=1)
        radii = np.concatenate([np.full((e, 1), cfg.robot_radius), radii], axis=1)
        pref = np.concatenate([world.robot_vel[:, None], pref], axis=1)
        speeds = np.concatenate([np.full((e, 1), cfg.robot_v_pref), speeds], axis=1)
        solve = np.concatenate([np.zeros((e, 1), dtype=bool), solve], axis=1)
    human_vel = orca_velocities(
        pos,
        vel,
        radii + cfg.orca.radius_pad,
        pref,
        speeds,
        True,
        solve,
        cfg.dt,
        cfg.orca.neighbor_dist,
        cfg.orca.max_neighbors,
        cfg.orca.time_horizon,
    )[:, 1 if cfg.visible_robot else 0 :]

    # Swept collision test.
    rel_start = world.human_pos - world.robot_pos[:, None]
    rel_end = rel_start + (human_vel - robot_vel[:, None]) * cfg.dt
    gaps = point_to_segment_distance(rel_start, rel_end) - world.human_radius - cfg.robot_radius
    d_min = gaps.min(axis=1) if n else np.full(e, np.inf)

    # Integration of the active environments.
    a2, a3 = active[:, None], active[:, None, None]
    world.robot_pos = np.where(a2, world.robot_pos + robot_vel * cfg.dt, world.robot_pos)
    world.robot_vel = np.where(a2, robot_vel, world.robot_vel)
    world.robot_theta = np.where(active, theta, world.robot_theta)
    world.human_pos = np.where(a3, world.human_pos + human_vel * cfg.dt, world.human_pos)
    world.human_vel = np.where(a3, human_vel, world.human_vel)
    world.steps = world.steps + active

    goal_dist = np.linalg.norm(world.robot_goal - world.robot_pos, axis=1)
    outcome = np.select(
        [d_min < 0, goal_dist < cfg.robot_radius, world.steps >= cfg.max_steps],
        [COLLISION, GOAL, TIMEOUT],
        RUNNING,
    )
    outcome = np.where(active, outcome, RUNNING)
    reward = compute_reward(outcome, d_min, world.start_dist, goal_dist, cfg.discomfort_dist)
    reward = np.where(active, reward, 0.0)

    if cfg.respawn_on_arrival and n:
        arrived = np.linalg.norm(world.human_goal - world.human_pos, axis=2) < world.human_radius
        arrived &= active[:, None]
        for env, human in zip(*np.nonzero(arrived), strict=True):
            world.human_goal[env, human] = orca_free_respawn(world, env, human)
    return StepResult(
        reward=reward,
        terminated=(outcome == GOAL) | (outcome == COLLISION),
        truncated=outcome == TIMEOUT,
        outcome=outcome,
        d_min=d_min,
    )


def orca_free_respawn(world: World, env: int, human: int) -> np.ndarray:
    from crowdplan.sim import scenarios

    return scenarios.respawn_goal(
        world.config, world._rngs[env], world.human_pos[env, human], world.human_v_pref[env, human]
    )


def random_actions(world: World, rng: np.random.Generator) -> np.ndarray:
    """Environments k % 3 == 0 head for the goal, 1 act at random, 2 mostly stand still.

    Discrete action indices on some steps, velocity commands (E, 2) on the others.
    """
    e = world.num_envs
    group = np.arange(e) % 3
    to_goal = world.robot_goal - world.robot_pos
    if world.config.kinematics == "holonomic" and rng.random() < 0.5:
        toward = 1 + (np.round(np.arctan2(to_goal[:, 1], to_goal[:, 0]) / (np.pi / 8)) % 16) * 5 + 4
        still = np.where(rng.random(e) < 0.9, 0, rng.integers(0, 81, e))
        choice = np.select([group == 0, group == 1], [toward, rng.integers(0, 81, e)], still)
        return choice.astype(np.int64)
    if world.config.kinematics == "unicycle":
        random = np.stack([rng.uniform(0.0, 1.0, e), rng.uniform(-0.8, 0.8, e)], axis=1)
        return np.where((group == 2)[:, None], 0.0, random)
    # World-frame commands; the world clips them to v_pref.
    random = rng.normal(0.0, 1.0, (e, 2))
    return np.select([group[:, None] == 0, group[:, None] == 1], [to_goal, random], 0.0)


def run_equivalence(config: WorldConfig, num_envs: int, steps: int, seed: int) -> dict:
    """Step kernel and reference from identical states along one random run; returns stats."""
    rng = np.random.default_rng(seed)
    world = World(config, num_envs)
    next_seed = 1000 + num_envs
    world.reset(list(range(1000, next_seed)))
    seen = {"outcomes": set(), "discomfort": 0, "inactive": 0}
    for _ in range(steps):
        actions = random_actions(world, rng)
        active = rng.random(num_envs) < 0.85 if rng.random() < 0.3 else None
        ref = copy.deepcopy(world)
        got = world.step(actions, active)
        want = reference_step(ref, actions, active)
        for name in STATE:
            np.testing.assert_allclose(getattr(world, name), getattr(ref, name), rtol=0, atol=ATOL)
        np.testing.assert_allclose(got.d_min, want.d_min, rtol=0, atol=ATOL)
        np.testing.assert_allclose(got.reward, want.reward, rtol=0, atol=ATOL)
        for name in ("outcome", "terminated", "truncated"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        assert got.outcome.dtype == np.int64 and got.terminated.dtype == bool
        seen["outcomes"].update(got.outcome.tolist())
        seen["discomfort"] += int(np.sum((got.outcome == RUNNING) & (got.reward < 0)))
        seen["inactive"] += 0 if active is None else int(np.sum(~active))
        done = np.flatnonzero(got.outcome != RUNNING)
        if len(done):
            world.reset(list(range(next_seed, next_seed + len(done))), done)
            next_seed += len(done)
    return seen


CONFIGS = {
    **{
        f"n{n}-{'visible' if vis else 'invisible'}": WorldConfig(humans=n, visible_robot=vis)
        for n in (0, 1, 5, 10)
        for vis in (False, True)
    },
    "unicycle": WorldConfig(humans=5, kinematics="unicycle", speed_sampling="exponential"),
    "unicycle-visible": WorldConfig(humans=5, kinematics="unicycle", visible_robot=True),
    "randomized": WorldConfig(humans=5, randomize_attributes=True, visible_robot=True),
    "respawn": WorldConfig(humans=5, respawn_on_arrival=True),
    "square": WorldConfig(scenario="square_crossing", humans=10),
    "world-frame": WorldConfig(humans=5, action_frame="world"),
    "rotated-goal": WorldConfig(humans=5, random_goal_direction=True),
    "few-neighbours": WorldConfig(humans=10).replace(orca={"max_neighbors": 3}),
}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_kernel_equals_numpy_reference(name):
    run_equivalence(CONFIGS[name], num_envs=6, steps=120, seed=len(name))


def test_equivalence_run_covers_every_branch():
    seen = run_equivalence(WorldConfig(humans=5), num_envs=8, steps=250, seed=1)
    assert seen["outcomes"] == {RUNNING, GOAL, COLLISION, TIMEOUT}
    assert seen["discomfort"] > 0 and seen["inactive"] > 0


def test_single_env_and_broadcast_action():
    world = World(WorldConfig(humans=5), num_envs=3)
    world.reset([1000, 1001, 1002])
    ref = copy.deepcopy(world)
    got, want = world.step(np.array([7])), reference_step(ref, np.array([7]), None)
    np.testing.assert_allclose(world.robot_pos, ref.robot_pos, rtol=0, atol=ATOL)
    np.testing.assert_allclose(got.d_min, want.d_min, rtol=0, atol=ATOL)


def test_bad_actions_leave_the_world_untouched():
    world = World(WorldConfig(humans=3), num_envs=2)
    world.reset([1000, 1001])
    before = copy.deepcopy(world)
    with pytest.raises(ValueError, match=r"action 81 is outside the valid range 0\.\.80"):
        world.step(np.array([3, 81]))
    with pytest.raises(ValueError, match="actions must be integers"):
        world.step(np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match=r"velocity commands must have shape \(2, 2\)"):
        world.step(np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"action indices must have shape \(2,\)"):
        world.step(np.array([1, 2, 3]))
    for name in STATE:
        np.testing.assert_array_equal(getattr(world, name), getattr(before, name))


def test_step_replaces_state_arrays():
    world = World(WorldConfig(humans=2))
    world.reset([0])
    old = world.robot_pos
    kept = old.copy()
    world.step(np.array([5]))
    np.testing.assert_array_equal(old, kept)  # a reference taken before the step keeps the state
    assert not np.array_equal(world.robot_pos, kept)


def test_observe_layout():
    world = World(WorldConfig(humans=4, randomize_attributes=True), num_envs=3)
    world.reset([5, 6, 7])
    world.step(np.array([3, 40, 80]))
    robot, humans, mask = world.observe()
    cfg = world.config
    expected_robot = np.column_stack(
        [
            world.robot_pos,
            world.robot_vel,
            np.full(3, cfg.robot_radius),
            world.robot_goal,
            np.full(3, cfg.robot_v_pref),
            world.robot_theta,
        ]
    )
    expected_humans = np.concatenate(
        [world.human_pos, world.human_vel, world.human_radius[..., None]], axis=2
    )
    np.testing.assert_array_equal(robot, expected_robot)
    np.testing.assert_array_equal(humans, expected_humans)
    assert mask.shape == (3, 4) and mask.dtype == bool and mask.all()
    again = world.observe()
    assert again[0] is not robot and again[1] is not humans  # fresh arrays on every call


def test_kernel_cache_key_follows_orca_source():
    """The step kernel's Numba cache key includes the hash of orca.py (cross-file staleness)."""
    from crowdplan.sim import world as world_module

    digest = hashlib.sha256(Path(orca.__file__).read_bytes()).digest()[:7]
    cells = [c.cell_contents for c in world_module._step_kernel.py_func.__closure__]
    assert int.from_bytes(digest, "little") in cells
